"""G's hysteresis thresholds chosen on validation frames by the full pipeline's accuracy."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic_training_frames import synthetic_frames

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.correction.pipeline import correct
from tof_mpd_ros.correction.weights import load_weights, save_weights
from tof_mpd_ros.evaluation.metrics import evaluate_frames
from tof_mpd_ros.training import TrainConfig, train
from tof_mpd_ros.training.edge_thresholds import THRESHOLD_GRID, choose_edge_thresholds

H, W = 40, 48


@pytest.fixture(scope="module")
def trained():
    frames = synthetic_frames(8, seed=0)
    config = TrainConfig(epochs=3, val_fraction=0.25, val_samples_per_frame=500,
                         max_samples_per_frame=600, tune_edge_thresholds=False)
    model, _ = train(frames, IntrinsicCalibration.identity(H, W), config, seed=0,
                     progress=False)
    return model, synthetic_frames(4, seed=77)


def test_choice_is_the_best_candidate_and_production_scores_the_same(trained) -> None:
    """The tuning path (R_F, G probabilities, hysteresis, geodesic filter) is the production
    path: the model with the chosen thresholds, run through ``correct``, scores exactly what
    the table says, and no candidate beats it in the boundary region."""
    model, val = trained
    choice = choose_edge_thresholds(model, val)
    assert choice is not None and len(choice.table) >= len(THRESHOLD_GRID)
    assert choice.table[0][:2] == (0.3, 0.6)  # the paper's default is always scored
    best = max(row[2] for row in choice.table)
    row = next(r for r in choice.table if r[:2] == (choice.low, choice.high))
    assert row[2] == best
    model.geodesic = type(model.geodesic)(edge_low=choice.low, edge_high=choice.high)
    ev = evaluate_frames([correct(model, f.range_mm, f.amplitude).range_mm for f in val],
                         [f.reference_mm for f in val])
    assert ev.boundary.at(5.0) == pytest.approx(row[2], abs=1e-9)
    assert ev.whole.at(5.0) == pytest.approx(row[3], abs=1e-9)


def test_thresholds_travel_with_the_weights(trained, tmp_path) -> None:
    model, _ = trained
    model.geodesic = type(model.geodesic)(edge_low=0.2, edge_high=0.75)
    save_weights(tmp_path / "w.npz", model)
    loaded = load_weights(tmp_path / "w.npz")
    assert (loaded.geodesic.edge_low, loaded.geodesic.edge_high) == (0.2, 0.75)
    a = correct(model, *_pair(), use_range_net=False)
    b = correct(loaded, *_pair(), use_range_net=False)
    np.testing.assert_array_equal(a.edges, b.edges)


def _pair() -> tuple[np.ndarray, np.ndarray]:
    f = synthetic_frames(1, seed=5)[0]
    return f.range_mm, f.amplitude


def test_trainer_stores_its_choice(tmp_path) -> None:
    frames = synthetic_frames(6, seed=1)
    config = TrainConfig(epochs=1, val_fraction=0.34, val_samples_per_frame=300,
                         max_samples_per_frame=300)
    model, _ = train(frames, IntrinsicCalibration.identity(H, W), config, seed=0,
                     progress=False, weights_path=tmp_path / "w.npz")
    chosen = model.metadata["edge_thresholds"]
    assert (model.geodesic.edge_low, model.geodesic.edge_high) == (chosen["low"],
                                                                   chosen["high"])
    loaded = load_weights(tmp_path / "w.npz")
    assert loaded.geodesic == model.geodesic
    assert loaded.metadata["edge_thresholds"]["f_alone"] == chosen["f_alone"]
