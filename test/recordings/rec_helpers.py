"""Helpers of the recordings tests: small deterministic frames and recordings."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.recordings import RecordingWriter

HEIGHT, WIDTH = 12, 16
INTRINSICS = Intrinsics(20.5, 21.25, 7.5, 5.75, WIDTH, HEIGHT)
MOD_FREQ = 24e6


def rigid(rng: np.random.Generator, scale: float = 0.5) -> np.ndarray:
    """A random (4, 4) float64 rigid transform, metres."""
    m = np.eye(4)
    m[:3, :3] = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    m[:3, 3] = rng.normal(scale=scale, size=3)
    return m


def make_frames(n: int, *, seed: int = 0, reference: bool = True, pose: bool = True,
                first_stamp: int = 1_700_000_000_000_000_000,
                intrinsics: Intrinsics = INTRINSICS) -> list[ToFFrame]:
    """n frames with NaNs in range, amplitude and reference, 50 ms apart."""
    rng = np.random.default_rng(seed)
    shape = intrinsics.shape
    frames = []
    for i in range(n):
        rng_mm = rng.uniform(150.0, 2500.0, shape).astype(np.float32)
        rng_mm[rng.random(shape) < 0.1] = np.nan
        amp = rng.uniform(0.0, 900.0, shape).astype(np.float32)
        amp[0, i % shape[1]] = np.nan
        ref = None
        if reference:
            ref = rng.uniform(150.0, 2500.0, shape).astype(np.float32)
            ref[rng.random(shape) < 0.2] = np.nan
        frames.append(ToFFrame(rng_mm, amp, intrinsics, mod_freq_hz=MOD_FREQ, reference_mm=ref,
                               stamp_ns=first_stamp + i * 50_000_000,
                               pose=rigid(rng) if pose else None))
    return frames


def write_recording(path: Path, frames: list[ToFFrame], *, hand_eye: np.ndarray | None = None,
                    **kwargs: object) -> Path:
    """Write frames; with ``hand_eye``, also TCP poses that compose to each frame's pose."""
    with RecordingWriter(path, **kwargs) as writer:  # type: ignore[arg-type]
        for frame in frames:
            if hand_eye is not None and frame.pose is not None:
                tcp = frame.pose @ np.linalg.inv(hand_eye)
                writer.write_frame(frame, tcp_pose=tcp, hand_eye=hand_eye)
            else:
                writer.write_frame(frame)
    return path


def assert_frames_equal(a: ToFFrame, b: ToFFrame, *, exact_range: bool = True) -> None:
    """Bit-exact comparison (NaN positions included) of two frames."""
    assert a.stamp_ns == b.stamp_ns
    assert a.intrinsics == b.intrinsics
    assert a.mod_freq_hz == b.mod_freq_hz
    assert a.amplitude.tobytes() == b.amplitude.tobytes()
    if exact_range:
        assert a.range_mm.tobytes() == b.range_mm.tobytes()
    assert (a.reference_mm is None) == (b.reference_mm is None)
    if exact_range and a.reference_mm is not None:
        assert a.reference_mm.tobytes() == b.reference_mm.tobytes()  # type: ignore[union-attr]
    assert (a.pose is None) == (b.pose is None)
    if a.pose is not None:
        assert a.pose.tobytes() == b.pose.tobytes()  # type: ignore[union-attr]
