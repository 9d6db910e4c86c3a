"""Localisation statistics against the noise model."""

from __future__ import annotations

import numpy as np

from tof_mpd_ros.mismatch.features import DESCRIPTORS, depth_edges
from tof_mpd_ros.mismatch.locate import locate


def _descriptors(edge_distance: np.ndarray) -> dict[str, np.ndarray]:
    shape = edge_distance.shape
    rng = np.random.default_rng(1)
    out = {name: rng.uniform(0, 1, shape) for name in DESCRIPTORS}
    out["edge_distance_px"] = edge_distance
    return out


def test_noise_only_is_not_flagged():
    rng = np.random.default_rng(0)
    sigma = np.full((40, 60), 3.0)
    res = [rng.normal(0, 3.0, sigma.shape) for _ in range(3)]
    _v, u = np.mgrid[0:40, 0:60]
    desc = [_descriptors(np.abs(u - 30.0))] * 3
    loc = locate(desc, res, [sigma] * 3)
    assert abs(loc["global"]["z"]) < 4.0
    assert 0.9 < loc["global"]["variance_ratio"] < 1.1
    assert loc["flagged"] == []


def test_edge_residual_is_located_near_edges():
    rng = np.random.default_rng(0)
    sigma = np.full((40, 60), 3.0)
    _v, u = np.mgrid[0:40, 0:60]
    dist = np.abs(u - 30.0)
    res = [rng.normal(0, 3.0, sigma.shape) + np.where(dist < 1.5, 6.0, 0.0) for _ in range(3)]
    loc = locate([_descriptors(dist)] * 3, res, [sigma] * 3)
    top = loc["flagged"][0]
    assert top["descriptor"] == "edge_distance_px" and top["low"] == 0.0
    assert top["z"] > 10.0 and abs(top["mean_mm"] - 6.0) < 1.0
    assert loc["correlations"]["edge_distance_px"]["residual"] < -0.1


def test_depth_edges_marks_both_sides_of_a_jump():
    ref = np.full((10, 10), 400.0)
    ref[:, 5:] = 300.0
    edges = depth_edges(ref)
    assert edges[:, 4].all() and edges[:, 5].all() and not edges[:, :4].any()
