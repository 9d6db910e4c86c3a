"""Assemble :class:`~tof_mpd_ros.frame.ToFFrame` objects from a stream of decoded messages.

Messages are paired by header stamp (``camera_to_base`` has no header: its MCAP log time, which
our writer sets to the stamp). A frame is emitted as soon as every topic the recording holds per
frame has arrived for its stamp; at most ``max_pending`` stamps wait, so memory stays bounded
and out-of-order arrival within that window is fine. ``camera_info`` and ``hand_eye`` may also
be static (fewer messages than range images): then the latest one seen is used.
"""

from __future__ import annotations

import logging
from collections import Counter, OrderedDict, deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InputError, RecordingError
from ..frame import ToFFrame
from . import convert
from .topics import Z_DEPTH, TopicNames

_log = logging.getLogger(__name__)

# Roles of the topics of TopicNames that make up a frame, and the message type each must hold.
ROLE_TYPES = {
    "range": "sensor_msgs/msg/Image", "amplitude": "sensor_msgs/msg/Image",
    "camera_info": "sensor_msgs/msg/CameraInfo", "reference": "sensor_msgs/msg/Image",
    "tcp_pose": "geometry_msgs/msg/PoseStamped", "hand_eye": "geometry_msgs/msg/TransformStamped",
    "camera_to_base": "std_msgs/msg/Float64MultiArray",
}
REQUIRED_ROLES = ("range", "amplitude", "camera_info")
_STICKY_CAPABLE = ("camera_info", "hand_eye")
_PER_FRAME_OPTIONAL = ("reference", "tcp_pose", "camera_to_base")


def normalise_type(msgtype: str) -> str:
    """``sensor_msgs/Image`` -> ``sensor_msgs/msg/Image`` (ROS 1 style names in schemas)."""
    parts = msgtype.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else msgtype


def topic_roles(topics: TopicNames) -> dict[str, str]:
    """Topic name -> role."""
    return {getattr(topics, role): role for role in ROLE_TYPES}


@dataclass
class Plan:
    """Which roles each frame waits for, derived from the recording's message counts.

    Attributes:
        per_frame: roles expected once per frame (same stamp as the range image).
        sticky: roles recorded less often than frames; the latest message is used.
    """

    per_frame: set[str] = field(default_factory=set)
    sticky: set[str] = field(default_factory=set)

    @classmethod
    def from_counts(cls, counts: Mapping[str, int]) -> Plan:
        """``counts``: messages per role in the recording (roles absent or 0 are not expected)."""
        n_range = counts.get("range", 0)
        plan = cls(per_frame={"range", "amplitude"})
        for role in _PER_FRAME_OPTIONAL:
            if counts.get(role, 0) > 0:
                plan.per_frame.add(role)
        for role in _STICKY_CAPABLE:
            n = counts.get(role, 0)
            if n >= n_range and n > 0:
                plan.per_frame.add(role)
            elif n > 0:
                plan.sticky.add(role)
        return plan


class FrameAssembler:
    """Pairs decoded messages into frames (see the module docstring).

    Args:
        source: the recording, for messages.
        plan: roles to wait for.
        convention: ``"radial"`` or ``"z"`` (range/reference hold z-depth; converted to radial).
        mod_freq_hz: modulation frequency given to every frame.
        skip_bad: drop (and count in ``dropped``) frames that cannot be built instead of raising.
        dropped: counter of drops by reason, shared with the reader.
        max_pending: stamps that may wait for their remaining messages.
    """

    def __init__(self, *, source: str, plan: Plan, convention: str, mod_freq_hz: float,
                 skip_bad: bool, dropped: Counter[str], max_pending: int = 8) -> None:
        self.source = source
        self.plan = plan
        self.convention = convention
        self.mod_freq_hz = mod_freq_hz
        self.skip_bad = skip_bad
        self.dropped = dropped
        self.max_pending = max_pending
        self._pending: OrderedDict[int, dict[str, Any]] = OrderedDict()
        self._latest: dict[str, Any] = {}
        self._done: deque[int] = deque(maxlen=256)

    def add(self, role: str, message: Any, log_time_ns: int) -> list[ToFFrame]:
        """Add one message of ``role``; return the frames it completes (oldest first)."""
        stamp = log_time_ns if role == "camera_to_base" else convert.stamp_ns_of(message)
        if role in _STICKY_CAPABLE:
            self._latest[role] = message
        if stamp in self._done:
            self.dropped[f"late {role} message"] += 1
            return []
        parts = self._pending.setdefault(stamp, {})
        if role in parts:
            self.dropped[f"duplicate {role} message"] += 1
            return []
        parts[role] = message
        out: list[ToFFrame] = []
        if self._complete(parts):
            out += self._emit(stamp)
        while len(self._pending) > self.max_pending:
            out += self._emit(next(iter(self._pending)))
        return out

    def finish(self) -> list[ToFFrame]:
        """Emit (or drop) everything still pending, oldest first."""
        out: list[ToFFrame] = []
        while self._pending:
            out += self._emit(next(iter(self._pending)))
        return out

    def _complete(self, parts: Mapping[str, Any]) -> bool:
        if not all(role in parts for role in self.plan.per_frame):
            return False
        return all(role in parts or role in self._latest for role in self.plan.sticky)

    def _part(self, parts: Mapping[str, Any], role: str) -> Any:
        """The role's message at this stamp; for camera_info/hand_eye else the latest one."""
        if role in parts:
            return parts[role]
        return self._latest.get(role)

    def _emit(self, stamp: int) -> list[ToFFrame]:
        parts = self._pending.pop(stamp)
        self._done.append(stamp)
        missing = [r for r in REQUIRED_ROLES if self._part(parts, r) is None]
        if missing:
            self.dropped[f"incomplete frame (no {', '.join(missing)})"] += 1
            _log.warning("%s: dropped the frame at %d ns: no %s message", self.source, stamp,
                         " or ".join(missing))
            return []
        for role in self.plan.per_frame - parts.keys():
            self.dropped[f"frame without {role}"] += 1
        try:
            return [self._build(stamp, parts)]
        except InputError as err:
            problem = f"{self.source}: frame at {stamp} ns: {err}"
            if not self.skip_bad:
                raise RecordingError(problem) from err
            self.dropped["bad frame"] += 1
            _log.warning("dropped %s", problem)
            return []

    def _build(self, stamp: int, parts: Mapping[str, Any]) -> ToFFrame:
        intrinsics = convert.intrinsics_of(self._part(parts, "camera_info"), "camera_info")
        range_mm = convert.range_mm_of(parts["range"], "range image")
        amplitude = convert.amplitude_of(parts["amplitude"], "amplitude image")
        reference = None
        if "reference" in parts:
            reference = convert.range_mm_of(parts["reference"], "reference image")
        images = {"range": range_mm, "amplitude": amplitude, "reference": reference}
        for name, image in images.items():
            if image is not None and image.shape != intrinsics.shape:
                raise InputError(f"{name} image is {image.shape[1]}x{image.shape[0]} but "
                                 f"camera_info says {intrinsics.width}x{intrinsics.height}"
                                 + ("" if name == "range" else
                                    f" (range image {range_mm.shape[1]}x{range_mm.shape[0]})"))
        if self.convention == Z_DEPTH:
            range_mm = intrinsics.z_to_radial(range_mm)
            reference = None if reference is None else intrinsics.z_to_radial(reference)
        return ToFFrame(range_mm, amplitude, intrinsics, mod_freq_hz=self.mod_freq_hz,
                        reference_mm=reference, stamp_ns=stamp, pose=self._pose(parts))

    def _pose(self, parts: Mapping[str, Any]) -> np.ndarray | None:
        """Camera-to-base (m): the exact matrix if recorded, else tcp_pose @ hand_eye."""
        if "camera_to_base" in parts:
            return convert.matrix_of_array(parts["camera_to_base"], "camera_to_base")
        tcp, hand_eye = parts.get("tcp_pose"), self._part(parts, "hand_eye")
        if tcp is None or hand_eye is None:
            return None
        return convert.matrix_of_pose(tcp) @ convert.matrix_of_transform(hand_eye)
