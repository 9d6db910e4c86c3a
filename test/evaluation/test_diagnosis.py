"""Measurements behind the benchmark's findings: region accuracy and what the misses are."""

from __future__ import annotations

import numpy as np

from tof_mpd_ros.evaluation.diagnosis import (
    REGIONS,
    MissTally,
    RegionTally,
    edge_distance,
    edges_by_orientation,
)
from tof_mpd_ros.evaluation.metrics import FrameAccumulator


def _frame(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    ref = np.full((40, 50), 400.0)
    ref[:, 25:] = 600.0                         # one vertical depth edge at column 25
    ref[0, :3] = np.nan                         # unscored pixels
    gt = np.zeros(ref.shape, bool)
    gt[:, 24:26] = True
    est = ref + rng.normal(0.0, 4.0, ref.shape)
    est[5, 5] = np.nan                          # no answer: a miss
    return est, ref, gt


def test_region_tally_equals_the_accumulator_on_each_region() -> None:
    tally = RegionTally(5.0)
    accs = {name: FrameAccumulator((5.0,)) for name, _, _ in REGIONS}
    for seed in range(3):
        est, ref, gt = _frame(seed)
        d = edge_distance(gt)
        tally.add({"m": est}, ref, d)
        for name, lo, hi in REGIONS:
            accs[name].add(est, ref, (d > lo) & (d <= hi))
    out = tally.result()
    for name, _, _ in REGIONS:
        curve = accs[name].result().boundary
        assert out[name]["m"]["within"] == curve.accuracy[0]
        assert out[name]["m"]["pixels"] == curve.n_pixels
        np.testing.assert_allclose(out[name]["m"]["mae_mm"], curve.mae_mm)
    assert out["edge (<= 2 px)"]["m"]["pixels"] == 3 * 40 * 6   # columns 22..27, 3 frames


def test_miss_tally_tells_noise_from_bias_and_finds_what_f_cannot_reach() -> None:
    ref = np.full((30, 40), 500.0)
    calibrated = ref.copy()
    calibrated[:, :20] -= 40.0                  # left half: 40 mm of distortion, beyond ±15
    checker = np.where((np.indices(ref.shape).sum(axis=0) % 2) == 0, 8.0, -8.0)
    tally = MissTally(clip_mm=15.0)
    tally.add({"biased": ref + 10.0, "noisy": ref + checker, "good": ref + 1.0}, ref,
              calibrated)
    out = tally.result()
    assert out["beyond_share"] == 0.5
    biased, noisy, good = (out["methods"][k] for k in ("biased", "noisy", "good"))
    assert biased["miss_share"] == 1.0 and biased["noise_limited"] == 0.0
    assert biased["beyond_clip"] == 0.5
    # ±8 mm alternating: every pixel misses, the 5×5 mean is within 5 mm everywhere
    assert noisy["miss_share"] == 1.0 and noisy["noise_limited"] == 1.0
    assert good["misses"] == 0 and good["noise_limited"] is None


def test_edges_by_orientation_counts_each_direction_and_the_named_group() -> None:
    gt = np.zeros((40, 50), bool)
    gt_group = np.full(gt.shape, -1)
    gt[5:35, 10], gt_group[5:35, 10] = True, 0       # a vertical edge: normal along x
    gt[30, 20:40], gt_group[30, 20:40] = True, 2     # a horizontal edge: normal along y
    pred = np.zeros(gt.shape, bool)
    group = np.full(gt.shape, -1)
    pred[5:35, 11], group[5:35, 11] = True, 0        # found, 1 px off, named right
    pred[30, 20:30], group[30, 20:30] = True, 0      # half found, named wrong
    pred[2, 30:40], group[2, 30:40] = True, 2        # spurious
    out = edges_by_orientation([pred], [group], [gt], [gt_group])
    assert out["0°"] == {"precision": 1.0, "recall": 1.0, "same_group": 30 / 40,
                         "n_pred": 40, "n_gt": 30}
    # 12 of 20: columns 20-29 and the two within 2 px past the last prediction
    assert out["90°"]["recall"] == 12 / 20 and out["90°"]["precision"] == 0.0
    assert out["45°"]["precision"] is None and out["45°"]["recall"] is None
