"""Geodesic K-nearest search (vs scipy's Dijkstra) and the paper's geodesic filter."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from tof_mpd_ros.correction.geodesic import geodesic_filter, geodesic_neighbours
from tof_mpd_ros.errors import InputError


def _grid_graph(edges: np.ndarray, step: float) -> coo_matrix:
    """The documented graph, built independently: 8-neighbours, no entering edge pixels, no
    diagonal move between two edge pixels."""
    h, w = edges.shape
    rows, cols, lengths = [], [], []
    for y in range(h):
        for x in range(w):
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    ny, nx = y + dy, x + dx
                    if (dy, dx) == (0, 0) or not (0 <= ny < h and 0 <= nx < w) or edges[ny, nx]:
                        continue
                    if dy and dx and edges[y, nx] and edges[ny, x]:
                        continue
                    rows.append(y * w + x)
                    cols.append(ny * w + nx)
                    lengths.append(step * (math.sqrt(2.0) if dy and dx else 1.0))
    return coo_matrix((lengths, (rows, cols)), shape=(h * w, h * w)).tocsr()


def _reference_knn(edges, valid, k, step, limit=np.inf):
    """K nearest valid pixels by scipy Dijkstra, ties by flat index, padded with -1 / inf."""
    dist = dijkstra(_grid_graph(edges, step), directed=True, limit=limit)
    dist[:, ~valid.ravel()] = np.inf
    n = dist.shape[0]
    idx = np.full((n, k), -1)
    out = np.full((n, k), np.inf)
    for p in range(n):
        order = np.lexsort((np.arange(n), np.round(dist[p], 9)))[:k]
        order = order[np.isfinite(dist[p, order])]
        idx[p, :order.size] = order
        out[p, :order.size] = dist[p, order]
    return idx, out


@pytest.mark.parametrize(("seed", "edge_fraction", "k", "step", "limit"),
                         [(0, 0.15, 20, 1.0, None), (1, 0.05, 81, 1.0, None),
                          (2, 0.25, 9, 0.5, None), (3, 0.1, 30, 1.0, 3.2)])
def test_neighbours_equal_scipy_dijkstra(seed, edge_fraction, k, step, limit):
    rng = np.random.default_rng(seed)
    edges = rng.random((21, 27)) < edge_fraction
    valid = rng.random((21, 27)) > 0.1
    idx, dist = geodesic_neighbours(edges, valid, k=k, step=step, max_distance=limit)
    ref_idx, ref_dist = _reference_knn(edges, valid, k, step, np.inf if limit is None else limit)
    assert idx.shape == (21 * 27, k) and idx.dtype == np.int32 and dist.dtype == np.float32
    np.testing.assert_allclose(dist, ref_dist, rtol=1e-6)  # inf == inf in the padding
    np.testing.assert_array_equal(idx, ref_idx)  # same tie order (distance, then flat index)


def test_obstacle_free_template_equals_the_search():
    # Sparse edges: most pixels take the precomputed template; all must match Dijkstra.
    edges = np.zeros((30, 36), bool)
    edges[5:25, 20] = True
    edges[12, 3:10] = True
    valid = np.ones_like(edges)
    valid[27, 30] = False
    idx, dist = geodesic_neighbours(edges, valid, k=81)
    ref_idx, ref_dist = _reference_knn(edges, valid, 81, 1.0)
    np.testing.assert_array_equal(idx, ref_idx)
    np.testing.assert_allclose(dist, ref_dist, rtol=1e-6)
    # An unobstructed pixel's 81 neighbours: octile distance <= 1 + 3√2 (a near-disc).
    p = 20 * 36 + 8
    assert dist[p, 0] == 0.0 and idx[p, 0] == p
    assert dist[p, -1] == pytest.approx(1 + 3 * math.sqrt(2), abs=1e-5)


def test_diagonal_edge_line_is_a_barrier_and_padding_is_reported():
    edges = np.zeros((12, 12), bool)
    for i in range(12):
        edges[i, 11 - i] = True  # an 8-connected anti-diagonal: only corner-cutting could cross
    idx, dist = geodesic_neighbours(edges, np.ones_like(edges), k=81)
    above = np.add.outer(np.arange(12), np.arange(12)) < 11
    p = 0  # top-left corner: the triangle above the line has 66 pixels < 81
    got = idx[p][idx[p] >= 0]
    assert got.size == 66 and above.ravel()[got].all()
    assert np.all(idx[p, 66:] == -1) and np.all(np.isinf(dist[p, 66:]))


def test_missing_pixels_are_crossed_but_never_neighbours():
    valid = np.ones((9, 15), bool)
    valid[:, 7] = False  # a full missing column
    idx, dist = geodesic_neighbours(np.zeros((9, 15), bool), valid, k=60)
    assert not np.isin(idx, np.flatnonzero(~valid.ravel())).any()
    p = 4 * 15 + 6  # next to the column: the other side is two steps away, through it
    assert 4 * 15 + 8 in idx[p]
    assert dist[p][list(idx[p]).index(4 * 15 + 8)] == pytest.approx(2.0)
    q = 4 * 15 + 7  # a missing pixel lists valid pixels only, starting at distance 1
    assert dist[q, 0] == pytest.approx(1.0)


def _step_image():
    r = np.full((30, 40), 300.0, np.float32)
    r[:, 20:] = 360.0
    return r


def test_filter_does_not_blur_across_a_marked_step():
    r = _step_image()
    edges = np.zeros(r.shape, bool)
    edges[:, 20] = True  # the first pixel of the far side is the edge
    out = geodesic_filter(r, edges)
    np.testing.assert_allclose(out, r, atol=1e-4)  # everywhere, the edge pixels included
    blurred = geodesic_filter(r, np.zeros(r.shape, bool))
    assert np.abs(blurred[:, 19] - 300.0).min() > 5.0  # without the edge: mixed across the step
    assert np.abs(blurred[:, 20] - 360.0).min() > 5.0
    np.testing.assert_allclose(blurred[:, :12], 300.0, atol=1e-4)  # far from the step: intact


def test_edge_pixels_join_the_side_they_resemble():
    r = _step_image()
    edges = np.zeros(r.shape, bool)
    edges[:, 20] = True
    r[:, 20] = 303.0  # a mixed pixel nearer the near side
    noisy = r + np.random.default_rng(0).normal(0.0, 1.0, r.shape).astype(np.float32)
    out = geodesic_filter(noisy, edges)
    assert np.abs(out[5:25, 20] - 300.0).max() < 1.0  # snapped to the near side, denoised
    assert np.abs(out[5:25, 21:] - 360.0).max() < 1.5


def test_constant_stays_constant_and_ramp_is_preserved():
    h, w = 40, 50
    const = np.full((h, w), 412.5, np.float32)
    const[10, 10] = np.nan
    edges = np.zeros((h, w), bool)
    edges[20:30, 25] = True
    np.testing.assert_allclose(geodesic_filter(const, edges), 412.5, atol=1e-4)
    y, x = np.mgrid[0:h, 0:w]
    ramp = (250.0 + 1.7 * x - 0.9 * y).astype(np.float32)
    out = geodesic_filter(ramp, np.zeros((h, w), bool))
    # The 81-neighbourhood is symmetric away from borders (radius <= 5.25 px): mean = centre.
    np.testing.assert_allclose(out[6:-6, 6:-6], ramp[6:-6, 6:-6], atol=1e-3)


@pytest.mark.parametrize("shape,density,open_share", [((15, 18), 0.1, (0.0, 0.05)),
                                                     ((40, 50), 0.002, (0.3, 1.0))])
def test_filter_is_the_weighted_mean_of_the_listed_neighbours(shape, density, open_share):
    """Dense edges (every pixel searched) and sparse ones (most pixels take the open template,
    whose means are one correlation of the frame): both are the weighted mean of the
    neighbour lists."""
    from tof_mpd_ros.correction import geodesic

    rng = np.random.default_rng(5)
    r = (300 + 20 * rng.random(shape)).astype(np.float32)
    r[3, 4] = np.nan
    edges = rng.random(r.shape) < density
    graph, _ = geodesic._prepare(edges, np.isfinite(r), 81, 1.0, None)
    assert open_share[0] <= graph.tmpl_ok.mean() <= open_share[1]
    idx, dist = geodesic_neighbours(edges, np.isfinite(r), k=81, step=1.0)
    w = np.where(idx >= 0, np.exp(-dist.astype(np.float64) ** 2 / (2 * 2.0**2)), 0.0)
    expected = (w * np.where(idx >= 0, r.ravel()[idx], 0.0)).sum(1) / w.sum(1)
    out = geodesic_filter(r, edges).ravel()
    non_edge = ~edges.ravel()
    np.testing.assert_allclose(out[non_edge], expected[non_edge], rtol=1e-6)


def test_missing_pixels_are_filled_or_kept():
    r = np.full((12, 12), 500.0, np.float32)
    r[5:7, 5:7] = np.nan
    np.testing.assert_allclose(geodesic_filter(r, np.zeros(r.shape, bool)), 500.0, atol=1e-4)
    kept = geodesic_filter(r, np.zeros(r.shape, bool), fill_missing=False)
    assert np.isnan(kept[5:7, 5:7]).all() and np.isfinite(kept).sum() == 140


def test_bad_inputs_raise_input_error():
    with pytest.raises(InputError, match="edges"):
        geodesic_filter(np.zeros((5, 5), np.float32), np.zeros((5, 6), bool))
    with pytest.raises(InputError, match="sigma"):
        geodesic_filter(np.zeros((5, 5), np.float32), np.zeros((5, 5), bool), sigma=0.0)
    with pytest.raises(InputError, match="k"):
        geodesic_neighbours(np.zeros((5, 5), bool), np.ones((5, 5), bool), k=0)
    with pytest.raises(InputError, match="valid"):
        geodesic_neighbours(np.zeros((5, 5), bool), np.ones((4, 5), bool))


def test_with_edges_it_denoises_boundaries_better_than_a_gaussian():
    import cv2

    rng = np.random.default_rng(11)
    truth = np.full((60, 80), 420.0, np.float32)
    truth[15:45, 20:60] = 340.0  # an 80 mm step all round a box
    noisy = truth + rng.normal(0.0, 3.0, truth.shape).astype(np.float32)
    edges = np.zeros(truth.shape, bool)
    edges[15:45, 20:60] = True
    edges[16:44, 21:59] = False  # the box's outline (foreground side), as ground_truth_edges
    near = cv2.dilate(edges.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    geo = geodesic_filter(noisy, edges)
    gauss = cv2.GaussianBlur(noisy, (0, 0), 2.0)
    rms = {name: float(np.sqrt(np.mean((img - truth)[near] ** 2)))
           for name, img in (("noisy", noisy), ("geodesic", geo), ("gaussian", gauss))}
    assert rms["geodesic"] < 0.5 * rms["noisy"]  # ~ 3 mm / sqrt(effective neighbours)
    assert rms["gaussian"] > 5 * rms["geodesic"]  # the Gaussian smears the 80 mm step


def test_border_templates_equal_the_search():
    # Large enough for the border templates (image >= 2r in both directions): sparse edges and
    # holes, some near the borders and corners, must give exactly the searched lists.
    rng = np.random.default_rng(7)
    edges = np.zeros((34, 41), bool)
    edges[3:15, 30] = True
    edges[28, 5:19] = True
    edges[1, 1] = True
    valid = rng.random(edges.shape) > 0.01
    valid[32, 39] = False
    idx, dist = geodesic_neighbours(edges, valid, k=81)
    ref_idx, ref_dist = _reference_knn(edges, valid, 81, 1.0)
    np.testing.assert_array_equal(idx, ref_idx)
    np.testing.assert_allclose(dist, ref_dist, rtol=1e-6)
    from tof_mpd_ros.correction.geodesic import _border_templates
    r, _, _, usable = _border_templates(81, 34, 41, 32.0)
    assert r > 0 and usable.sum() == (2 * r + 1) ** 2      # the templates were in play


def test_the_kernels_graph_is_named() -> None:
    """_prepare hands the kernels a Graph whose fields mean what their names say."""
    from tof_mpd_ros.correction.geodesic import _MOVES, Graph, _prepare

    rng = np.random.default_rng(3)
    edges = rng.random((12, 17)) < 0.1
    valid = rng.random((12, 17)) > 0.1
    graph, length = _prepare(edges, valid, 9, 1.0, None)
    assert isinstance(graph, Graph) and (graph.h, graph.w, graph.k) == (12, 17, 9)
    np.testing.assert_array_equal(graph.valid, valid.ravel())
    np.testing.assert_array_equal(graph.obstacle, (edges | ~valid).ravel())
    np.testing.assert_array_equal(graph.move_off, _MOVES[:, 0] * 17 + _MOVES[:, 1])
    np.testing.assert_array_equal(graph.move_diag, _MOVES[:, 2] == 1)
    assert graph.tmpl_off.shape == graph.tmpl_rank.shape == (9,)
    assert not graph.tmpl_ok[edges.ravel()].any()       # an obstacle in the footprint
    assert graph.next_axis.shape == graph.next_diag.shape == length.shape
