"""Synthetic ToF-like frames for the baseline tests (imported by the other test_baselines_*
files), and checks that the generator does what the tests assume.

A frame: a tilted table plane ~400 mm away with 2–3 boxes 40–90 mm closer; amplitude =
albedo · (400 / range)²; the "measurement" adds (a) a multipath-like over-shoot of up to
``overshoot_mm`` on pixels that have a much closer surface within 4 px — a distortion that depends
on the local patch — and (b) Gaussian noise whose sigma scales with 1 / sqrt(amplitude).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage


@dataclass
class Frame:
    """Test frame: (H, W) float32 arrays; range and reference in mm, NaN = invalid/missing."""

    range_mm: np.ndarray
    amplitude: np.ndarray
    reference_mm: np.ndarray | None
    flat: np.ndarray  # (H, W) bool: > 4 px from any depth discontinuity of the truth


def make_scene(rng: np.random.Generator, h: int = 60, w: int = 80
               ) -> tuple[np.ndarray, np.ndarray]:
    """(truth_mm, albedo): (H, W) float64 radial range in mm and reflectance in [0.3, 1]."""
    yy, xx = np.mgrid[:h, :w].astype(np.float64)
    g = rng.uniform(-0.5, 0.5, 2)
    truth = 400.0 + g[0] * (xx - w / 2) + g[1] * (yy - h / 2)
    albedo = np.full((h, w), rng.uniform(0.5, 0.9))
    for _ in range(rng.integers(2, 4)):
        bh, bw = rng.integers(h // 5, h // 2), rng.integers(w // 6, w // 3)
        y0, x0 = rng.integers(0, h - bh), rng.integers(0, w - bw)
        truth[y0:y0 + bh, x0:x0 + bw] -= rng.uniform(40.0, 90.0)
        albedo[y0:y0 + bh, x0:x0 + bw] = rng.uniform(0.3, 1.0)
    return truth, albedo


def make_frame(rng: np.random.Generator, *, h: int = 60, w: int = 80, noise_mm: float = 3.0,
               overshoot_mm: float = 0.0, holes: int = 0) -> Frame:
    """One synthetic frame (see the module doc); ``holes`` 3×3 invalid squares in the input."""
    truth, albedo = make_scene(rng, h, w)
    amplitude = albedo * (400.0 / truth) ** 2
    nearer = truth - ndimage.minimum_filter(truth, size=9, mode="nearest")
    # The tilt alone makes a 9x9 neighbour up to ~4 mm nearer: only real steps count.
    r = truth + overshoot_mm * np.clip((nearer - 10.0) / 30.0, 0.0, 1.0)
    r = r + rng.normal(0.0, 1.0, r.shape) * noise_mm * np.sqrt(0.7 / amplitude)
    for _ in range(holes):
        y, x = rng.integers(1, h - 2), rng.integers(1, w - 2)
        r[y - 1:y + 2, x - 1:x + 2] = np.nan
    edge = ndimage.maximum_filter(np.abs(np.gradient(truth)[0]) + np.abs(np.gradient(truth)[1]),
                                  size=9) > 5.0
    return Frame(r.astype(np.float32), amplitude.astype(np.float32), truth.astype(np.float32),
                 ~edge)


def rmse(estimate: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    """Root-mean-square error in mm over ``mask`` & both finite."""
    ok = mask & np.isfinite(estimate) & np.isfinite(reference)
    return float(np.sqrt(np.mean((estimate[ok] - reference[ok]) ** 2)))


def test_generator_is_deterministic_and_has_both_regions() -> None:
    a = make_frame(np.random.default_rng(3), overshoot_mm=10.0)
    b = make_frame(np.random.default_rng(3), overshoot_mm=10.0)
    np.testing.assert_array_equal(a.range_mm, b.range_mm)
    assert 0.3 < a.flat.mean() < 0.95


def test_overshoot_is_local_to_nearer_surfaces() -> None:
    fr = make_frame(np.random.default_rng(4), noise_mm=0.0, overshoot_mm=10.0)
    err = fr.range_mm - fr.reference_mm
    assert np.all(err >= -1e-3)
    assert err[fr.flat].max() < 1e-3  # flat interiors are undistorted
    assert err.max() > 9.0
