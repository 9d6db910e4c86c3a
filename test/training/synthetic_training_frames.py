"""Small synthetic frames with a learnable, patch-dependent multipath-like distortion.

A tilted table with one box on it. The ToF range over-shoots on the table near the box's base
(a concave corner: indirect light adds path length), by ``bump_mm * exp(-d / 2 px)`` where d is
the pixel distance to the box, and carries 0.5 mm noise. The distortion is a function of the
11 x 11 patch (the step is visible in it), so F can learn it; G can learn the box outline.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.frame import ToFFrame


def synthetic_frame(rng: np.random.Generator, h: int = 40, w: int = 48,
                    bump_mm: float = 12.0) -> ToFFrame:
    intr = Intrinsics.from_fov(w, h, 40.0)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    table = rng.uniform(380, 460) + rng.uniform(-0.8, 0.8) * (xx - w / 2) \
        + rng.uniform(-0.8, 0.8) * (yy - h / 2)
    bh, bw = rng.integers(10, 20), rng.integers(10, 24)
    top, left = rng.integers(2, h - bh - 2), rng.integers(2, w - bw - 2)
    box = np.zeros((h, w), bool)
    box[top:top + bh, left:left + bw] = True
    height = rng.uniform(60, 140)
    reference = np.where(box, table - height, table)
    dist = ndimage.distance_transform_edt(~box)
    bump = np.where(box, 0.0, bump_mm * np.exp(-(dist - 1) / 2.0))
    albedo = np.where(box, rng.uniform(0.3, 0.9), rng.uniform(0.3, 0.9))
    amplitude = albedo * (400.0 / reference) ** 2 * (1 + rng.normal(0, 0.01, (h, w)))
    measured = reference + bump + rng.normal(0, 0.5, (h, w))
    ref = reference.copy()
    ref[rng.random((h, w)) < 0.02] = np.nan            # a few missing reference pixels
    return ToFFrame(measured.astype(np.float32), amplitude.astype(np.float32), intr,
                    reference_mm=ref.astype(np.float32))


def synthetic_frames(n: int, seed: int, **kwargs) -> list[ToFFrame]:
    rng = np.random.default_rng(seed)
    return [synthetic_frame(rng, **kwargs) for _ in range(n)]
