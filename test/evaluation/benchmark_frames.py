"""Small frames for the evaluation tests: a table at ~400 mm with one nearer box, a
multipath-like over-shoot beside it, amplitude-dependent noise and a +6 mm offset, in capture
sessions an hour apart."""

from __future__ import annotations

import numpy as np

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.frame import ToFFrame

H, W = 36, 48
HOUR_NS = 3_600 * 10**9


def frame(rng: np.random.Generator, stamp_ns: int) -> ToFFrame:
    """A table at ~400 mm with one nearer box; the measurement over-shoots next to the box
    (multipath-like), carries amplitude-dependent noise and a +6 mm offset."""
    xx = np.mgrid[:H, :W][1].astype(np.float64)
    truth = 400.0 + 0.3 * (xx - W / 2) + rng.uniform(-5, 5)
    y0, x0 = rng.integers(6, 14), rng.integers(8, 20)
    truth[y0:y0 + 14, x0:x0 + 16] -= rng.uniform(50, 80)
    albedo = np.where(truth < 370, 0.9, 0.5)
    amplitude = albedo * (400.0 / truth) ** 2
    from scipy import ndimage

    nearer = truth - ndimage.minimum_filter(truth, size=7, mode="nearest")
    measured = truth + 6.0 + 10.0 * np.clip((nearer - 10) / 30, 0, 1)
    measured += rng.normal(0, 1.5, truth.shape) / np.sqrt(amplitude)
    reference = truth.copy()
    reference[:3, :5] = np.nan                       # a missing patch, as SL leaves them
    return ToFFrame(measured.astype(np.float32), amplitude.astype(np.float32),
                    Intrinsics.from_fov(W, H, 74.0), reference_mm=reference.astype(np.float32),
                    stamp_ns=stamp_ns)


def frames(seed: int, n_sessions: int, per_session: int) -> list[ToFFrame]:
    rng = np.random.default_rng(seed)
    return [frame(rng, s * HOUR_NS + k * 10**9) for s in range(n_sessions)
            for k in range(per_session)]


