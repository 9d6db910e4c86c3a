"""A collection session: a directory of recording parts, resumable after any interruption.

``SESSION/part_000/``, ``SESSION/part_001/``, ... are ordinary recordings. A run never reopens
an earlier part (an interrupted writer may have left it without a summary); it writes the views
still missing into a new part. Which views are present is read back from the recordings
themselves — a view counts once a complete frame whose camera pose matches the planned pose is
readable — so the recordings are the only ledger and cannot disagree with it.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..errors import RecordingError
from ..pose import rotation_angle
from .plan import PlannedView

log = logging.getLogger(__name__)

POSE_TOLERANCE_M = 0.002
ANGLE_TOLERANCE_RAD = 0.01


def parts(session: str | Path) -> list[Path]:
    """The session's recording parts in order."""
    return sorted(p for p in Path(session).glob("part_*") if p.is_dir())


def next_part(session: str | Path) -> Path:
    """Path of the next part to write (not created)."""
    existing = parts(session)
    number = int(existing[-1].name.split("_")[1]) + 1 if existing else 0
    return Path(session) / f"part_{number:03d}"


def recorded_poses(session: str | Path) -> list[np.ndarray]:
    """Camera-to-base poses (metres) of every complete frame in the session.

    A part that cannot be read at all (e.g. killed before its first chunk) is skipped and
    logged; what it held was never on disk.
    """
    from ..recordings import RecordingReader

    poses: list[np.ndarray] = []
    for part in parts(session):
        try:
            with RecordingReader(part) as reader:
                poses.extend(f.pose for f in reader.frames() if f.pose is not None)
        except RecordingError as err:
            log.warning("skipping unreadable part %s: %s", part, err)
    return poses


def matches(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two (4, 4) poses (metres) are the same viewpoint within the tolerances."""
    if np.linalg.norm(a[:3, 3] - b[:3, 3]) > POSE_TOLERANCE_M:
        return False
    return rotation_angle(a, b) <= ANGLE_TOLERANCE_RAD


def completed_views(session: str | Path, plan: list[PlannedView],
                    hand_eye_m: np.ndarray) -> dict[int, int]:
    """How many complete frames the session holds for each planned view index."""
    counts = {view.index: 0 for view in plan}
    for pose in recorded_poses(session):
        for view in plan:
            if matches(pose, view.camera_to_base_m(hand_eye_m)):
                counts[view.index] += 1
                break
    return counts


# ------------------------------------------------------------------ calibration sessions
# A hand-eye calibration session holds calibration recordings (calibration.hand_eye_io): their
# frames carry the TCP pose but no camera pose (the hand-eye transform is what they are for), so its
# views are matched on the TCP pose.


def is_calibration_part(part: str | Path) -> bool | None:
    """Whether a part is a hand-eye calibration recording; None if it cannot be read."""
    from ..calibration.hand_eye_io import KEY_BOARD
    from ..recordings import RecordingReader

    try:
        with RecordingReader(part) as reader:
            return KEY_BOARD in reader.custom_data
    except RecordingError:
        return None


def parts_of_other_kind(session: str | Path, calibration: bool) -> list[Path]:
    """Readable parts that are not of the wanted kind (calibration or ordinary recordings)."""
    return [p for p in parts(session) if is_calibration_part(p) not in (None, calibration)]


def completed_calibration_views(session: str | Path,
                                plan: list[PlannedView]) -> dict[int, int]:
    """How many complete calibration views (TCP pose, ToF amplitude and SL image) the session
    holds for each planned view index, matched on the TCP pose."""
    from ..calibration.hand_eye_io import read_hand_eye_recording

    counts = {view.index: 0 for view in plan}
    for part in parts(session):
        try:
            captures = read_hand_eye_recording(part).captures
        except RecordingError as err:
            log.warning("skipping unreadable part %s: %s", part, err)
            continue
        for capture in captures:
            if capture.tcp_to_base_m is None or capture.sl_image is None or \
                    capture.tof_amplitude is None:
                continue
            for view in plan:
                if matches(capture.tcp_to_base_m, view.tcp_to_base_m):
                    counts[view.index] += 1
                    break
    return counts
