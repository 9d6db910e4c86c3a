"""Hand–eye calibration recordings: write the views, read them back as captures.

A calibration recording is an ordinary tof_mpd_ros recording (rosbag2 MCAP) with, per view and
all under the view's header stamp:

* the ToF frame (range, amplitude, CameraInfo) and the TCP pose, as
  :meth:`~tof_mpd_ros.recordings.RecordingWriter.write_frame` writes them (no hand-eye
  transform: that is what the calibration finds);
* the SL camera's intensity image on ``/sl/image_raw`` (``sensor_msgs/msg/Image``, mono8 or
  32FC1) and its ``sensor_msgs/msg/CameraInfo`` on ``/sl/camera_info``, frame ``sl_optical_frame``;

and in ``custom_data``: ``tof_mpd_ros.hand_eye.board`` (the board as JSON: squares, square size
in mm, albedos) and the two SL topic names. A simulated recording may also hold
``tof_mpd_ros.hand_eye.sim_truth`` (the true transforms, JSON, metres) so a report can show the
error; the calibration never reads it.

The ``collector`` node writes the same format view by view (:func:`hand_eye_custom_data`,
:func:`write_hand_eye_view`) into the parts of a session; :func:`read_hand_eye_recording` reads
one part or a whole session directory (all parts merged, so a resumed calibration session
solves as one).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import Intrinsics
from ..errors import CalibrationError, InputError, RecordingError
from ..frame import ToFFrame
from ..recordings import RecordingReader, RecordingWriter, convert, msgdefs
from .hand_eye import HandEyeCapture
from .hand_eye_board import CalibrationBoard

KEY_BOARD = "tof_mpd_ros.hand_eye.board"
KEY_SL_IMAGE = "tof_mpd_ros.hand_eye.sl_image_topic"
KEY_SL_INFO = "tof_mpd_ros.hand_eye.sl_camera_info_topic"
KEY_SIM_TRUTH = "tof_mpd_ros.hand_eye.sim_truth"
# Written by the collector into recordings made with a calibration result (hand_eye_file).
KEY_CALIBRATION_FILE = "tof_mpd_ros.hand_eye.calibration_file"
KEY_SL_TO_TOF = "tof_mpd_ros.hand_eye.sl_to_tof"
SL_IMAGE_TOPIC = "/sl/image_raw"
SL_CAMERA_INFO_TOPIC = "/sl/camera_info"
SL_FRAME_ID = "sl_optical_frame"
SL_ENCODINGS = ("mono8", "mono16", "32FC1", "64FC1")

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class HandEyeRecording:
    """What :func:`read_hand_eye_recording` returns.

    Attributes:
        captures: one per ToF frame, in stamp order (a view without TCP pose or SL image keeps
            ``None`` there, so the solver reports it).
        board: the recorded target.
        tof_intrinsics, sl_intrinsics: of the ToF amplitude and SL images.
        custom_data: the recording's ``custom_data``.
    """

    captures: list[HandEyeCapture]
    board: CalibrationBoard
    tof_intrinsics: Intrinsics
    sl_intrinsics: Intrinsics
    custom_data: dict[str, str] = field(default_factory=dict)

    def sim_truth(self) -> dict[str, np.ndarray] | None:
        """The simulated cell's true transforms (4x4, metres) if the recording has them."""
        text = self.custom_data.get(KEY_SIM_TRUTH)
        if text is None:
            return None
        return {k: np.asarray(v, dtype=np.float64) for k, v in json.loads(text).items()}


def write_hand_eye_recording(path: str | Path, frames: Sequence[ToFFrame],
                             tcp_to_base_m: Sequence[np.ndarray], sl_images: Sequence[np.ndarray],
                             board: CalibrationBoard, sl_intrinsics: Intrinsics, *,
                             sim_truth: Mapping[str, np.ndarray] | None = None,
                             overwrite: bool = False) -> None:
    """Write a calibration recording.

    Args:
        path: recording directory to create.
        frames: ToF frames (range mm, amplitude), stamps unique; ``pose`` is not written.
        tcp_to_base_m: (4, 4) TCP poses in the base frame, metres, one per frame.
        sl_images: (H, W) uint8 (mono8) or float32 (32FC1) SL intensity images, one per frame.
        board: the target.
        sl_intrinsics: of the SL images.
        sim_truth: optional true transforms (name -> (4, 4), metres) of a simulation.
        overwrite: replace an existing recording.
    """
    if not len(frames) == len(tcp_to_base_m) == len(sl_images):
        raise InputError(f"need one TCP pose and one SL image per ToF frame, got "
                         f"{len(frames)} frames, {len(tcp_to_base_m)} poses, "
                         f"{len(sl_images)} images")
    custom = hand_eye_custom_data(board, sim_truth=sim_truth)
    with RecordingWriter(path, custom_data=custom, overwrite=overwrite) as writer:
        for frame, tcp, image in zip(frames, tcp_to_base_m, sl_images, strict=True):
            write_hand_eye_view(writer, frame, tcp, image, sl_intrinsics)


def hand_eye_custom_data(board: CalibrationBoard, *,
                         sim_truth: Mapping[str, np.ndarray] | None = None) -> dict[str, str]:
    """The ``custom_data`` of a calibration recording (for ``RecordingWriter(custom_data=)``).

    Args:
        board: the target.
        sim_truth: optional true transforms (name -> (4, 4), metres) of a simulation.
    """
    custom = {KEY_BOARD: json.dumps(board.as_dict()), KEY_SL_IMAGE: SL_IMAGE_TOPIC,
              KEY_SL_INFO: SL_CAMERA_INFO_TOPIC}
    if sim_truth is not None:
        custom[KEY_SIM_TRUTH] = json.dumps({k: np.asarray(v).tolist()
                                            for k, v in sim_truth.items()})
    return custom


def write_hand_eye_view(writer: RecordingWriter, frame: ToFFrame, tcp_to_base_m: np.ndarray,
                        sl_image: np.ndarray, sl_intrinsics: Intrinsics) -> None:
    """Append one calibration view to an open writer, all under ``frame.stamp_ns``.

    The SL image and CameraInfo are written first and the ToF frame last: ``write_frame``
    closes the MCAP chunk, so a view whose TCP pose is readable after a crash also has its SL
    image.

    Args:
        writer: an open writer made with :func:`hand_eye_custom_data`.
        frame: the ToF frame (range mm, amplitude); its ``pose`` is not written.
        tcp_to_base_m: (4, 4) TCP pose in the base frame, metres.
        sl_image: (H, W) uint8 (mono8) or float (32FC1) SL intensity image.
        sl_intrinsics: of the SL image.
    """
    pixels = np.asarray(sl_image)
    encoding = "mono8" if pixels.dtype == np.uint8 else "32FC1"
    stamp = frame.stamp_ns
    writer.write(SL_IMAGE_TOPIC, msgdefs.IMAGE, convert.image_dict(
        pixels if encoding == "mono8" else pixels.astype(np.float32), encoding, stamp,
        SL_FRAME_ID), stamp)
    writer.write(SL_CAMERA_INFO_TOPIC, msgdefs.CAMERA_INFO, convert.camera_info_dict(
        sl_intrinsics, stamp, SL_FRAME_ID), stamp)
    unposed = ToFFrame(frame.range_mm, frame.amplitude, frame.intrinsics,
                       mod_freq_hz=frame.mod_freq_hz, stamp_ns=frame.stamp_ns)
    writer.write_frame(unposed, tcp_pose=tcp_to_base_m)

def _board_of(custom: Mapping[str, str], path: Path) -> CalibrationBoard:
    text = custom.get(KEY_BOARD)
    if text is None:
        raise RecordingError(f"{path}: no board description (custom_data {KEY_BOARD}); pass "
                             "the board explicitly")
    try:
        return CalibrationBoard.from_dict(json.loads(text))
    except (json.JSONDecodeError, AttributeError, InputError) as err:
        raise RecordingError(f"{path}: custom_data {KEY_BOARD} is not a board: {err}") from err


def _by_stamp(reader: RecordingReader, topics: Mapping[str, str]) -> dict[str, dict[int, Any]]:
    """Per role, the messages of its topic keyed by header stamp (ns)."""
    out: dict[str, dict[int, Any]] = {role: {} for role in topics}
    role_of = {topic: role for role, topic in topics.items()}
    for m in reader.messages(set(topics.values())):
        out[role_of[m.topic]][convert.stamp_ns_of(m.message)] = m.message
    return out


def is_session(path: str | Path) -> bool:
    """Whether ``path`` is a collection session (``part_NNN`` recordings), not a recording."""
    path = Path(path)
    if not path.is_dir() or (path / "metadata.yaml").exists() or any(path.glob("*.mcap")):
        return False
    return any(p.is_dir() for p in path.glob("part_*"))


def read_hand_eye_recording(path: str | Path, *,
                            board: CalibrationBoard | None = None) -> HandEyeRecording:
    """Read a calibration recording's views, or those of every part of a session.

    Args:
        path: recording directory (or ``.mcap`` file), or a session directory holding
            ``part_NNN`` recordings (the collector's; parts are merged in stamp order, parts
            that cannot be read at all are skipped with a warning).
        board: the target, when the recording does not describe it.

    Returns:
        The captures, board, and both cameras' intrinsics.

    Raises:
        RecordingError: unreadable recording, no ToF frames, no SL CameraInfo, no board; for
            a session also parts with different boards or intrinsics.
    """
    path = Path(path)
    if is_session(path):
        return _read_session(path, board)
    return _read_one(path, board)


def _read_session(path: Path, board: CalibrationBoard | None) -> HandEyeRecording:
    parts: list[HandEyeRecording] = []
    for part in sorted(p for p in path.glob("part_*") if p.is_dir()):
        try:
            parts.append(_read_one(part, board))
        except RecordingError as err:
            log.warning("skipping part %s: %s", part, err)
    if not parts:
        raise RecordingError(f"{path}: no readable calibration recording among its parts")
    first = parts[0]
    for part in parts[1:]:
        if (part.board != first.board or part.tof_intrinsics != first.tof_intrinsics
                or part.sl_intrinsics != first.sl_intrinsics):
            raise RecordingError(f"{path}: parts differ in board or camera intrinsics; solve "
                                 "them separately")
    captures = sorted((c for p in parts for c in p.captures), key=lambda c: c.stamp_ns)
    captures = [HandEyeCapture(i, c.stamp_ns, c.tcp_to_base_m, c.tof_amplitude, c.sl_image)
                for i, c in enumerate(captures)]
    return HandEyeRecording(captures, first.board, first.tof_intrinsics, first.sl_intrinsics,
                            first.custom_data)


def _read_one(path: Path, board: CalibrationBoard | None) -> HandEyeRecording:
    with RecordingReader(path) as reader:
        custom = reader.custom_data
        board = board or _board_of(custom, path)
        frames = sorted(reader.frames(), key=lambda f: f.stamp_ns)
        topics = {"tcp": reader.topic_names.tcp_pose,
                  "sl_image": custom.get(KEY_SL_IMAGE, SL_IMAGE_TOPIC),
                  "sl_info": custom.get(KEY_SL_INFO, SL_CAMERA_INFO_TOPIC)}
        parts = _by_stamp(reader, topics)
    if not frames:
        raise RecordingError(f"{path}: no ToF frames")
    if not parts["sl_info"]:
        raise RecordingError(f"{path}: no SL camera info on {topics['sl_info']}")
    sl_intrinsics = convert.intrinsics_of(next(iter(parts["sl_info"].values())), "SL camera info")
    captures = []
    for i, frame in enumerate(frames):
        if frame.intrinsics != frames[0].intrinsics:
            raise RecordingError(f"{path}: ToF intrinsics change at frame {i}")
        tcp = parts["tcp"].get(frame.stamp_ns)
        image = parts["sl_image"].get(frame.stamp_ns)
        captures.append(HandEyeCapture(
            index=i, stamp_ns=frame.stamp_ns,
            tcp_to_base_m=None if tcp is None else convert.matrix_of_pose(tcp),
            tof_amplitude=frame.amplitude,
            sl_image=None if image is None else convert.image_pixels(image, SL_ENCODINGS,
                                                                     "SL image")[0]))
    return HandEyeRecording(captures, board, frames[0].intrinsics, sl_intrinsics, dict(custom))


def load_hand_eye_json(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """The transforms of a ``tof-mpd calibrate hand-eye -o OUT.json`` result, for recordings.

    Returns:
        ((4, 4) float64 ToF camera -> flange, (4, 4) float64 SL camera -> ToF camera), metres.

    Raises:
        CalibrationError: the file is missing, not JSON, or lacks the transforms.
    """
    try:
        summary = json.loads(Path(path).read_text())
        matrices = [np.asarray(summary[k]["matrix_m"], dtype=np.float64)
                    for k in ("camera_to_flange", "sl_to_tof")]
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
        raise CalibrationError(f"{path}: not a hand-eye result (expected JSON with "
                               f"camera_to_flange.matrix_m and sl_to_tof.matrix_m): {err}"
                               ) from err
    for m in matrices:
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise CalibrationError(f"{path}: transforms must be finite 4x4 matrices")
    return matrices[0], matrices[1]
