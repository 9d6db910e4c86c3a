"""The approximate geodesic filter measured by benchmarks/bench_geodesic_approximation.py is an
edge-aware smoother worth measuring: an edge line is a barrier, and off edges it smooths as
much as the exact filter (same sigma). Otherwise its accuracy figures would compare nothing."""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from tof_mpd_ros.correction import geodesic

# benchmarks/ is a folder of scripts, not a package.
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_geodesic_approximation as bench

MODES = (cv2.ximgproc.DTF_RF, cv2.ximgproc.DTF_NC)


def two_planes(noise_mm: float = 2.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(60, 80) float32 range, mm: 400 mm left of column 40, 300 mm right, noise; the edge map
    marks column 40."""
    rng = np.random.default_rng(seed)
    r = np.full((60, 80), 400.0)
    r[:, 40:] = 300.0
    r += rng.normal(0.0, noise_mm, r.shape)
    edges = np.zeros(r.shape, bool)
    edges[:, 40] = True
    return r.astype(np.float32), edges


@pytest.mark.parametrize("mode", MODES)
def test_an_edge_line_is_a_barrier(mode: int) -> None:
    r, edges = two_planes()
    out = bench.domain_transform(r, edges, 2.0, mode)
    # A 100 mm step leaking 1 % would move the pixels next to the edge by 1 mm.
    assert np.abs(out[:, 36:40] - 400.0).max() < 4.0
    assert np.abs(out[:, 41:45] - 300.0).max() < 4.0
    # The edge pixels take one side's value, not the mean of both.
    side = np.minimum(np.abs(out[:, 40] - 400.0), np.abs(out[:, 40] - 300.0))
    assert side.max() < 4.0


@pytest.mark.parametrize("mode", MODES)
def test_off_edges_it_smooths_about_as_much_as_the_exact_filter(mode: int) -> None:
    r, edges = two_planes(noise_mm=3.0, seed=1)
    interior = np.zeros(r.shape, bool)
    interior[5:-5, 5:30] = interior[5:-5, 50:-5] = True
    truth = np.where(np.arange(80)[None, :] < 40, 400.0, 300.0) * np.ones((60, 1))
    raw = np.std((r - truth)[interior])
    exact = np.std((geodesic.geodesic_filter(r, edges) - truth)[interior])
    approx = np.std((bench.domain_transform(r, edges, 2.0, mode) - truth)[interior])
    assert raw == pytest.approx(3.0, rel=0.1)
    assert exact < raw / 4  # about 1/sqrt(effective neighbours)
    assert exact / 2 < approx < exact * 2


def test_missing_pixels_are_filled_from_their_own_side_and_isolated_ones_stay_missing() -> None:
    r, edges = two_planes()
    r[20:23, 30:33] = np.nan
    out = bench.domain_transform(r, edges, 2.0, cv2.ximgproc.DTF_RF)
    assert np.abs(out[20:23, 30:33] - 400.0).max() < 4.0
    alone = np.full((10, 10), np.nan, np.float32)
    assert np.isnan(bench.domain_transform(alone, np.zeros((10, 10), bool), 2.0,
                                           cv2.ximgproc.DTF_RF)).all()
