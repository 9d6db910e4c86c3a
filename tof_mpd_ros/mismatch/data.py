"""Real frames for the mismatch tool: loading, checks, camera motion and the train/held-out split.

Frames come from a recording directory / ``.mcap`` file or the NPZ interchange
(docs/recordings.md). Every frame needs its reference (the reference *is* the scene the simulator
predicts from).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import MismatchError, TofMpdError
from ..frame import ToFFrame
from ..pose import matrix_to_rotvec
from ..sim.tof import CameraMotion

#: frames further apart than this are separate stops of the arm: the camera is taken at rest
MAX_MOTION_GAP_S = 0.5
#: tile size (pixels) of the checkerboard split used when there is a single frame
SPLIT_TILE_PX = 8


def load_frames(path: str | Path) -> list[ToFFrame]:
    """Frames of a recording (directory or ``.mcap``) or an interchange ``.npz``, opened by
    :func:`tof_mpd_ros.recordings.iter_frames` (so ``.NPZ`` too); a folder laid out like the
    Azure Kinect sample (``depth_000.npy``, ``ir_000.npy``, ``calibration.json``) becomes one
    frame with its plane-fit reference (:mod:`.realdata`), and so does an Analog Devices folder
    (``depth_mode3.npy`` ...: its mode 3).

    Raises:
        MismatchError: the path does not exist, holds no frame, or a frame has no reference.
    """
    path = Path(path)
    if not path.exists():
        raise MismatchError(f"{path}: no such file or directory")
    from .realdata import adi_frame, azure_kinect_frame, is_adi_dir, is_azure_kinect_dir
    if is_azure_kinect_dir(path):
        return [azure_kinect_frame(path)[0]]
    if is_adi_dir(path):
        return [adi_frame(path, 3)]   # the long-range mode; the CLI's --mode picks another
    from ..recordings import iter_frames
    try:
        frames = list(iter_frames(path))
    except TofMpdError as err:
        raise MismatchError(f"{path}: cannot read frames: {err}") from err
    check_frames(frames)
    return frames


def check_frames(frames: Sequence[ToFFrame]) -> None:
    """Raise :class:`MismatchError` unless the frames share a camera and all have references."""
    if not frames:
        raise MismatchError("no frames to analyse")
    first = frames[0]
    for i, f in enumerate(frames):
        if not isinstance(f, ToFFrame):
            raise MismatchError(f"frame {i}: expected a ToFFrame, got {type(f).__name__}")
        if f.reference_mm is None or not np.isfinite(f.reference_mm).any():
            raise MismatchError(f"frame {i} has no reference: the mismatch tool predicts each "
                                "frame from its reference range image")
        if f.intrinsics != first.intrinsics or f.mod_freq_hz != first.mod_freq_hz:
            raise MismatchError(f"frame {i}: camera differs from frame 0 ({f.intrinsics}, "
                                f"{f.mod_freq_hz} Hz)")


def camera_motion(frames: Sequence[ToFFrame]) -> list[CameraMotion | None]:
    """Camera velocity at each frame from the poses and stamps (central differences).

    The velocity is expressed in each frame's camera optical frame: linear in mm/s, angular in
    rad/s. Frames without a pose, or whose neighbours are more than ``MAX_MOTION_GAP_S`` away
    (the arm stopped at a viewpoint), get None (at rest).

    Returns:
        One entry per frame.
    """
    out: list[CameraMotion | None] = []
    n = len(frames)
    for i, f in enumerate(frames):
        lo, hi = max(i - 1, 0), min(i + 1, n - 1)
        a, b = frames[lo], frames[hi]
        dt = (b.stamp_ns - a.stamp_ns) * 1e-9
        gap = max((f.stamp_ns - a.stamp_ns) * 1e-9, (b.stamp_ns - f.stamp_ns) * 1e-9)
        if (lo == hi or f.pose is None or a.pose is None or b.pose is None or dt <= 0
                or gap > MAX_MOTION_GAP_S):
            out.append(None)
            continue
        rot_i = f.pose[:3, :3]
        linear = rot_i.T @ (b.pose[:3, 3] - a.pose[:3, 3]) * 1e3 / dt
        rel = matrix_to_rotvec(a.pose[:3, :3].T @ b.pose[:3, :3])
        # rel is in frame a's axes; frames are close, so it is taken as frame i's
        angular = rel / dt
        out.append(CameraMotion(tuple(float(v) for v in linear),
                                tuple(float(v) for v in angular)))
    return out


def camera_speed(motion: CameraMotion | None) -> tuple[float, float]:
    """``(linear mm/s, angular rad/s)`` magnitudes of a motion (0, 0 at rest)."""
    if motion is None:
        return 0.0, 0.0
    return (float(np.linalg.norm(motion.linear_mm_s)),
            float(np.linalg.norm(motion.angular_rad_s)))


@dataclass(frozen=True)
class Split:
    """Which pixels of each frame fit the parameters and which judge them.

    Attributes:
        train: per frame, (H, W) bool mask of training pixels.
        test: per frame, (H, W) bool mask of held-out pixels.
        how: ``"frames"`` (alternate frames) or ``"tiles"`` (checkerboard of tiles).
    """

    train: tuple[np.ndarray, ...]
    test: tuple[np.ndarray, ...]
    how: str


def split_frames(frames: Sequence[ToFFrame], tile_px: int = SPLIT_TILE_PX) -> Split:
    """Alternate frames (even = train, odd = held-out); a single frame is split by tiles.

    Alternating keeps both halves spread over the recording, so slow drifts and the whole pose
    range are represented in each.
    """
    shape = frames[0].intrinsics.shape
    if len(frames) >= 2:
        train = tuple(np.full(shape, i % 2 == 0) for i in range(len(frames)))
        test = tuple(~m for m in train)
        return Split(train, test, "frames")
    v, u = np.mgrid[0:shape[0], 0:shape[1]]
    board = ((v // tile_px) + (u // tile_px)) % 2 == 0
    return Split((board,), (~board,), "tiles")
