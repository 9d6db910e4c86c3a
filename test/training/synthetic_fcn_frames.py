"""Small synthetic frames for the fcn trainer: a distortion a per-pixel calibration cannot remove.

A tilted table with one box on it (random place, size, height and albedo). The measured range is
the reference plus

* a range-dependent bias, ``bias_per_m * (R* - 400 mm)`` (the part a per-pixel calibration
  could remove);
* multipath from the box onto the table, ``box_mm * albedo_box * exp(-d / 8 px)`` with d the
  table pixel's distance to the box: it depends on a region up to ~30 px away and on how
  bright that region is, and changes from frame to frame, so no per-pixel correction removes it;
* Gaussian noise of ``noise_mm``;

and ``flying`` (a fraction) of the box's outline pixels read the mean of the two sides (flying
pixels, tens of mm off). 2 % of the reference pixels are missing.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.frame import ToFFrame


def fcn_frame(rng: np.random.Generator, h: int = 48, w: int = 64, *, box_mm: float = 20.0,
              bias_per_m: float = 40.0, noise_mm: float = 0.5, flying: float = 0.0
              ) -> ToFFrame:
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    table = rng.uniform(380, 460) + rng.uniform(-0.8, 0.8) * (xx - w / 2) \
        + rng.uniform(-0.8, 0.8) * (yy - h / 2)
    bh, bw = rng.integers(8, h // 2), rng.integers(8, w // 2)
    top, left = rng.integers(2, h - bh - 2), rng.integers(2, w - bw - 2)
    box = np.zeros((h, w), bool)
    box[top:top + bh, left:left + bw] = True
    reference = np.where(box, table - rng.uniform(40, 120), table)
    box_albedo, table_albedo = rng.uniform(0.1, 1.0), rng.uniform(0.3, 0.6)
    dist = ndimage.distance_transform_edt(~box)
    multipath = np.where(box, 0.0, box_mm * box_albedo * np.exp(-(dist - 1) / 8.0))
    measured = (reference + bias_per_m * (reference - 400.0) / 1000.0 + multipath
                + rng.normal(0, noise_mm, (h, w)))
    if flying > 0:
        outline = box & ~ndimage.binary_erosion(box)
        fly = outline & (rng.random((h, w)) < flying)
        measured[fly] = 0.5 * (reference[fly] + table[fly])
    albedo = np.where(box, box_albedo, table_albedo)
    amplitude = albedo * (400.0 / reference) ** 2 * (1 + rng.normal(0, 0.01, (h, w)))
    ref = reference.copy()
    ref[rng.random((h, w)) < 0.02] = np.nan
    return ToFFrame(measured.astype(np.float32), amplitude.astype(np.float32),
                    Intrinsics.from_fov(w, h, 40.0), reference_mm=ref.astype(np.float32))


def fcn_frames(n: int, seed: int, **kwargs) -> list[ToFFrame]:
    rng = np.random.default_rng(seed)
    return [fcn_frame(rng, **kwargs) for _ in range(n)]
