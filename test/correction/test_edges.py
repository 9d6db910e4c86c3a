"""Edges: ground-truth Canny on reference range, the networks' NMS + hysteresis, Canny baseline."""

from __future__ import annotations

import numpy as np
import pytest

from tof_mpd_ros.correction.edges import (
    GROUP_NORMALS,
    canny_edges,
    canny_score_map,
    edge_map_from_responses,
    fill_missing,
    ground_truth_edges,
    hysteresis,
    non_maximum_suppression,
    orientation_group,
    unsure_edge_decisions,
)
from tof_mpd_ros.errors import InputError


def _box_scene(h: int = 60, w: int = 80) -> np.ndarray:
    """Table at 400 mm with a 50 mm-tall box (range 350 mm) at rows 20..39, cols 25..54."""
    r = np.full((h, w), 400.0, np.float32)
    r[20:40, 25:55] = 350.0
    return r


def test_box_outline_is_one_pixel_on_the_foreground():
    edges, group = ground_truth_edges(_box_scene())
    outline = np.zeros_like(edges)
    outline[20:40, 25:55] = True
    outline[21:39, 26:54] = False  # the box's own border pixels (foreground side of the step)
    assert np.array_equal(edges, outline)
    assert np.all(group[20, 26:54] == 2) and np.all(group[21:39, 25] == 0)  # normals 90°, 0°
    assert np.all(group[~edges] == -1) and group.dtype == np.int8


def test_tilted_plane_and_small_steps_are_not_edges():
    y, x = np.mgrid[0:60, 0:80].astype(np.float32)
    plane = 300.0 + 4.5 * x + 2.0 * y  # |step strength| = 2 * 4.9 = 9.85 mm < low (10 mm)
    assert not ground_truth_edges(plane)[0].any()
    small = np.full((60, 80), 400.0, np.float32)
    small[:, 40:] = 391.0  # a 9 mm step: below the low threshold
    assert not ground_truth_edges(small)[0].any()
    weak = np.full((60, 80), 400.0, np.float32)
    weak[:, 40:] = 385.0  # a 15 mm step: weak everywhere, never strong -> dropped by hysteresis
    assert not ground_truth_edges(weak)[0].any()
    assert ground_truth_edges(weak, low=10.0, high=14.0)[0][:, 40].all()


def test_missing_pixels_make_no_edges_but_a_shadowed_step_is_kept():
    y, x = np.mgrid[0:60, 0:80].astype(np.float32)
    plane = 300.0 + 3.0 * x + 2.0 * y
    plane[20:35, 20:40] = np.nan  # a hole inside a tilted surface
    plane[:, :6] = np.nan  # a missing border strip
    assert not ground_truth_edges(plane)[0].any()
    clean_edges, _ = ground_truth_edges(_box_scene())
    shadowed = _box_scene()
    shadowed[20:40, 55:58] = np.nan  # a 3 px occlusion shadow right of the box
    edges, _ = ground_truth_edges(shadowed)
    assert np.array_equal(edges, clean_edges)  # the silhouette is still on the box's last column
    assert not edges[np.isnan(shadowed)].any()


def test_fill_missing_continues_rims_and_fills_shadows_with_background():
    r = np.array([[350, 350, np.nan, np.nan, 400, 400]], np.float32).repeat(3, axis=0)
    filled = fill_missing(r, np.isfinite(r))
    np.testing.assert_array_equal(filled[1], [350, 350, 400, 400, 400, 400])
    ramp = np.array([[10, 12, np.nan, 16, 18]], np.float32)
    np.testing.assert_array_equal(fill_missing(ramp, np.isfinite(ramp))[0], [10, 12, 12, 16, 18])


def test_orientation_groups_follow_the_normal_modulo_180():
    angles = np.radians([0, 44, 46, 90, 135, 180, 200, 250, 300])
    g = orientation_group(np.cos(angles), np.sin(angles))
    np.testing.assert_array_equal(g, [0, 1, 1, 2, 3, 0, 0, 2, 3])
    assert GROUP_NORMALS.tolist() == [[0, 1], [1, 1], [1, 0], [1, -1]]


def test_nms_thins_a_blurred_ridge_to_one_pixel_per_row():
    h, w = 30, 40
    x = np.arange(w, dtype=np.float32)
    ridge = 0.9 * np.exp(-0.5 * ((x - 20.4) / 1.5) ** 2)  # crest between columns 20 and 21
    scores = np.zeros((4, h, w), np.float32)
    scores[0] = ridge  # vertical line -> horizontal normal (group 0)
    scores[2] = 0.5 * ridge  # a weaker competing orientation must not win
    edges, strength = edge_map_from_responses(scores)
    assert np.array_equal(np.flatnonzero(edges.any(axis=0)), [20])
    assert edges[:, 20].all()
    np.testing.assert_allclose(strength[:, 20], ridge[20], rtol=1e-6)
    assert np.count_nonzero(strength) == h  # NMS leaves one maximum per row


def test_nms_thins_a_diagonal_ridge_between_pixels():
    h = w = 40
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    d = (x - y - 0.5) / np.sqrt(2)  # crest exactly between two diagonals of pixels
    scores = np.zeros((4, h, w), np.float32)
    scores[3] = 0.9 * np.exp(-0.5 * (d / 1.2) ** 2)  # normal along (-x, +y)... and (x, -y)
    edges, _ = edge_map_from_responses(scores)
    rows, cols = np.nonzero(edges)
    assert edges.sum() >= h - 2  # one pixel per row, no gaps
    assert np.all((cols - rows == 0) | (cols - rows == 1))
    assert len(np.unique(rows)) == len(rows)


def test_hysteresis_keeps_weak_segments_connected_to_strong_only():
    scores = np.zeros((4, 20, 30), np.float32)
    scores[2, 5, 2:20] = 0.4  # weak horizontal line...
    scores[2, 5, 10] = 0.8  # ...with one strong pixel
    scores[2, 14, 2:20] = 0.4  # isolated weak line
    scores[2, 17, 25] = 0.7  # isolated strong dot
    edges, strength = edge_map_from_responses(scores, low=0.3, high=0.6)
    assert edges[5, 2:20].all() and not edges[14].any() and edges[17, 25]
    assert edges.sum() == 18 + 1
    assert strength[14, 5] == pytest.approx(0.4)  # NMS strength is reported without hysteresis


def test_canny_baseline_finds_the_box_and_score_map_reproduces_thresholds():
    rng = np.random.default_rng(3)
    r = _box_scene() + rng.normal(0.0, 1.0, (60, 80)).astype(np.float32)
    r[0, 0] = np.nan
    edges = canny_edges(r)
    assert edges.dtype == bool and not edges[0, 0]
    assert edges[20:40, 23:27].any(axis=1).all()  # left side found within a pixel or two
    assert edges.sum() < 2 * 96  # outline only, not the noise
    highs = np.array([10.0, 20.0, 40.0, 80.0])
    score = canny_score_map(r, highs=highs)
    for t in highs:
        assert np.array_equal(score >= t, canny_edges(r, low=0.5 * t, high=t))
    assert not canny_edges(r, high=80.0, low=40.0).any()  # a 50 mm step is not an 80 mm step


def test_amplitude_masks_the_baseline():
    r = _box_scene()
    amp = np.ones_like(r)
    amp[:, :40] = 0.0
    assert not canny_edges(r, amp)[:, :40].any()


def test_bad_inputs_raise_input_error():
    with pytest.raises(InputError, match="scores"):
        edge_map_from_responses(np.zeros((3, 5, 5), np.float32))
    with pytest.raises(InputError, match="reference_mm"):
        ground_truth_edges(np.zeros((2, 5, 5), np.float32))
    with pytest.raises(InputError, match="low"):
        ground_truth_edges(_box_scene(), low=30.0, high=20.0)
    edges, group = ground_truth_edges(np.full((8, 8), np.nan, np.float32))
    assert not edges.any() and (group == -1).all()


def test_staircase_thinning_keeps_8_connectivity():
    import cv2

    from tof_mpd_ros.correction.edges import non_maximum_suppression, thin_staircases

    for seed in range(6):
        rng = np.random.default_rng(seed)
        field = cv2.GaussianBlur(rng.random((80, 80)).astype(np.float32), (0, 0), 3.0)
        gy, gx = np.gradient(field)
        maxima = non_maximum_suppression(np.hypot(gx, gy), orientation_group(gx, gy))
        thinned = thin_staircases(maxima)
        assert thinned.sum() < maxima.sum()  # random ridges do contain staircase corners
        n_before, _ = cv2.connectedComponents(maxima.astype(np.uint8), connectivity=8)
        n_after, _ = cv2.connectedComponents(thinned.astype(np.uint8), connectivity=8)
        assert n_before == n_after


def _heads(logits: np.ndarray) -> tuple[np.ndarray, ...]:
    """(best, group, logit, margin) of (4, H, W) head logit differences, as the kernels give
    them (the probability is the float32 rounding of the float64 sigmoid)."""
    order = np.sort(logits, axis=0)
    logit = order[-1].astype(np.float32)
    best = (1.0 / (1.0 + np.exp(-logit.astype(np.float64)))).astype(np.float32)
    return best, np.argmax(logits, axis=0), logit, (order[-1] - order[-2]).astype(np.float32)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("pair_share", [1.0, 0.5])
def test_rechecking_the_unsure_pixels_restores_the_exact_nms_and_hysteresis(
        seed: int, pair_share: float) -> None:
    """Head logits off by up to ``error``, two of them by up to ``pair_error`` from each other (a
    reduced precision): once the pixels :func:`unsure_edge_decisions` names carry their exact
    values again, non-maximum suppression plus hysteresis give exactly the exact map, while
    without it they do not."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    h, w, error, low, high = 60, 80, 0.3, 0.6, 0.95
    pair_error = 2 * error * pair_share
    # smooth ridges of edge evidence: many near-ties along them, as trained G heads give
    field = gaussian_filter(rng.normal(size=(4, h, w)), (0, 2, 2)) * 40.0 - 2.0
    exact = _heads(field.astype(np.float32))
    # a shared offset plus independent parts: |error| <= error, pairwise <= pair_error
    shared = rng.uniform(-1, 1) * (error - pair_error / 2)
    offset = shared + rng.uniform(-pair_error / 2, pair_error / 2, field.shape)
    noisy = _heads((field + offset).astype(np.float32))
    valid = rng.random((h, w)) > 0.02

    def nms_hysteresis(best: np.ndarray, group: np.ndarray) -> np.ndarray:
        best = np.where(valid, best, 0.0).astype(np.float32)
        return hysteresis(non_maximum_suppression(best, group), best, low, high)

    unsure = unsure_edge_decisions(np.where(valid, noisy[2], -np.inf), noisy[3], noisy[1],
                                   valid, error, pair_error, low=low, high=high)
    merged = [np.where(unsure, e, n) for e, n in zip(exact[:2], noisy[:2], strict=True)]
    want = nms_hysteresis(*exact[:2])
    assert want.sum() > 50                                        # edges to decide
    np.testing.assert_array_equal(nms_hysteresis(*merged), want)
    assert (nms_hysteresis(*noisy[:2]) != want).sum() > 0         # the recheck was needed
    assert unsure.mean() < 0.5 and not (unsure & ~valid).any()


def test_nothing_is_unsure_where_no_pixel_can_reach_the_high_threshold() -> None:
    """Undecided heads everywhere (probability ~0.5, as untrained weights give) below a high
    threshold no error can reach: no pixel can be an edge, so none needs rechecking; with an
    error that reaches it, the whole undecided run is unsure."""
    rng = np.random.default_rng(0)
    logit = rng.normal(0.0, 0.05, (30, 40)).astype(np.float32)
    margin = np.full_like(logit, 0.01)
    group = np.zeros(logit.shape, np.int64)
    valid = np.ones(logit.shape, bool)
    # sigmoid(0.15 + 0.3) = 0.61 < 0.95: certain non-edges
    assert not unsure_edge_decisions(logit, margin, group, valid, 0.3, 0.6, low=0.3,
                                     high=0.95).any()
    assert unsure_edge_decisions(logit, margin, group, valid, 3.0, 6.0, low=0.3,
                                 high=0.95).all()
    for error, pair_error in ((-0.1, 0.0), (0.1, 0.3)):
        with pytest.raises(InputError):
            unsure_edge_decisions(logit, margin, group, valid, error, pair_error)
