"""The paper's metrics on small hand-computed examples."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tof_mpd_ros.errors import InputError
from tof_mpd_ros.evaluation import (
    accuracy_curve,
    boundary_region,
    edge_precision_recall,
    evaluate_frames,
)

NAN = np.nan


def test_accuracy_curve_counts_strictly_below_and_invalid_estimates_fail():
    reference = np.array([[100.0, 100.0, 100.0], [100.0, 100.0, NAN]])
    estimate = np.array([[100.5, 102.0, 97.0], [NAN, 130.0, 100.0]])
    # errors: 0.5, 2 (not < 2), 3, no estimate (failure), 30; the last pixel is not evaluated.
    c = accuracy_curve(estimate, reference, thresholds=[1, 2, 3, 5, 40])
    assert c.n_pixels == 5 and c.n_invalid_estimates == 1
    np.testing.assert_allclose(c.accuracy, [1 / 5, 1 / 5, 2 / 5, 3 / 5, 4 / 5])
    assert c.mae_mm == pytest.approx((0.5 + 2 + 3 + 30) / 4)
    assert c.rmse_mm == pytest.approx(math.sqrt((0.25 + 4 + 9 + 900) / 4))
    assert c.at(3) == pytest.approx(0.4)
    json.dumps(c.to_dict())


def test_mask_restricts_and_empty_regions_give_null_statistics():
    reference = np.full((2, 2), 50.0)
    estimate = np.array([[50.0, 60.0], [50.0, 50.0]])
    mask = np.array([[False, True], [False, False]])
    c = accuracy_curve(estimate, reference, [5.0], mask=mask)
    assert c.n_pixels == 1 and c.accuracy == (0.0,) and c.mae_mm == 10.0
    empty = accuracy_curve(estimate, reference, [5.0], mask=np.zeros((2, 2), bool))
    assert empty.n_pixels == 0 and math.isnan(empty.accuracy[0])
    assert json.loads(json.dumps(empty.to_dict()))["accuracy"] == [None]


def test_boundary_region_is_a_5px_band_around_the_reference_edge():
    reference = np.full((30, 40), 400.0, np.float32)
    reference[:, 20:] = 340.0  # edge on column 20 (the nearer side of the step)
    region = boundary_region(reference)
    assert np.array_equal(np.flatnonzero(region.all(axis=0)), np.arange(15, 26))
    assert not region[:, :15].any() and not region[:, 26:].any()
    assert not boundary_region(np.full((10, 10), 400.0)).any()
    edges = np.zeros((9, 9), bool)
    edges[4, 4] = True
    disc = boundary_region(np.zeros((9, 9)), 2.0, edges=edges)
    assert disc.sum() == 13  # lattice points within Euclidean radius 2


def test_evaluate_frames_pools_pixels_not_frame_means():
    ref = np.full((2, 10, 10), 400.0)
    est = ref.copy()
    est[0, :, :] += 3.0  # frame 0: all 100 pixels 3 mm off
    est[1, 0, 0] = NAN  # frame 1: one failure, 99 exact
    ref[1, 5:, :] = NAN  # frame 1: only 50 evaluated pixels
    result = evaluate_frames(est, ref, thresholds=[1.0, 5.0])
    assert result.whole.n_pixels == 150 and result.n_frames == 2
    np.testing.assert_allclose(result.whole.accuracy, [49 / 150, 149 / 150])
    assert result.boundary.n_pixels == 0  # flat frames have no boundary
    masks = [np.ones((10, 10), bool), np.zeros((10, 10), bool)]
    masked = evaluate_frames(list(est), list(ref), [1.0], boundary_masks=masks)
    assert masked.boundary.n_pixels == 100 and masked.boundary.accuracy == (0.0,)
    json.dumps(result.to_dict())
    with pytest.raises(InputError, match="same number of frames"):
        evaluate_frames(est, ref[:1])


def test_edge_precision_recall_with_tolerance():
    gt = np.zeros((20, 20), bool)
    gt[10, 2:18] = True  # 16 ground-truth pixels
    score = np.zeros((20, 20))
    score[12, 2:10] = 0.9  # 8 px, 2 px below: correct within tolerance 2
    score[16, 2:18] = 0.5  # 16 px, 6 px off: false
    curve = edge_precision_recall(score, gt, thresholds=[0.4, 0.8, 0.95], tolerance_px=2)
    # t=0.4: P = 8/24. A GT pixel (10, c) is within 2 px of (12, c') only for c' = c
    # (sqrt(2² + 1²) > 2), so the recalled GT pixels are columns 2..9: R = 8/16.
    np.testing.assert_allclose(curve.precision, [8 / 24, 1.0, 1.0])
    np.testing.assert_allclose(curve.recall, [0.5, 0.5, 0.0])
    f1 = 2 * 1.0 * 0.5 / (1.0 + 0.5)
    assert curve.max_f1 == pytest.approx(f1) and curve.best_threshold == 0.8
    tight = edge_precision_recall(score, gt, thresholds=[0.8], tolerance_px=1)
    assert tight.precision == (0.0,) and tight.recall == (0.0,) and tight.f1 == (0.0,)
    json.dumps(curve.to_dict())


def test_edge_precision_recall_pools_frames_and_respects_valid():
    gt = np.zeros((10, 10), bool)
    gt[5, :] = True
    perfect = gt.astype(float)
    valid = np.ones((10, 10), bool)
    valid[:, 5:] = False
    c = edge_precision_recall([perfect, np.zeros((10, 10))], [gt, gt], [0.5],
                              valid=[valid, valid])
    assert c.n_gt == 10 and c.precision == (1.0,) and c.recall == (0.5,)


def test_region_accuracy_splits_by_distance_to_the_edges() -> None:
    """A step edge at column 20: the estimate is 10 mm off within 2 px of it and exact
    elsewhere, so the edge region is 0 % within 5 mm and the others 100 %."""
    from tof_mpd_ros.evaluation.components import region_accuracy
    from tof_mpd_ros.evaluation.diagnosis import REGIONS

    ref = np.full((30, 40), 500.0)
    gt = np.zeros(ref.shape, bool)
    gt[:, 20] = True
    est = ref.copy()
    cols = np.abs(np.arange(40) - 20)
    est[:, cols <= 2] += 10.0
    out = region_accuracy({"F": [est]}, [ref], [gt])
    assert list(out) == [name for name, _, _ in REGIONS]
    edge, near, interior = (out[name]["F"] for name, _, _ in REGIONS)
    assert edge["within"] == 0.0 and edge["mae_mm"] == 10.0 and edge["pixels"] == 30 * 5
    assert near["within"] == 1.0 and near["pixels"] == 30 * 6
    assert interior["within"] == 1.0 and interior["pixels"] == 30 * 40 - 30 * 11
