"""The registry's uniform interface and the grid search."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_baselines_synthetic import make_frame

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.correction.encoding import EncodingConfig
from tof_mpd_ros.errors import InputError
from tof_mpd_ros.evaluation.baselines import (
    BASELINES,
    JBF,
    PD,
    RFWF,
    grid_search,
    joint_bilateral,
    total_variation,
    weighted_median,
)
from tof_mpd_ros.evaluation.baselines.grid import within_threshold
from tof_mpd_ros.frame import ToFFrame

SMALL = {  # constructor arguments that keep every method fast on 60x80 frames
    "RF-WF": {"n_estimators": 4, "max_depth": 6, "samples_per_frame": 500},
    "RFD": {"n_estimators": 4, "max_depth": 6, "samples_per_frame": 300,
            "encoding": EncodingConfig(range_min_mm=250.0, range_max_mm=500.0,
                                       amplitude_max=2.0)},
    "PD": {"n_atoms": 64},
}


@pytest.fixture(scope="module")
def frames() -> list:
    rng = np.random.default_rng(20)
    return [make_frame(rng, noise_mm=3.0, overshoot_mm=8.0, holes=3) for _ in range(4)]


def test_registry_names_the_six_paper_baselines() -> None:
    assert list(BASELINES) == ["JBF", "WMF", "RF-WF", "RFD", "TV", "PD"]
    for name, cls in BASELINES.items():
        assert cls.name == name
        assert set(cls.param_grid) <= set(cls.apply_param_names())


@pytest.mark.parametrize("name", list(BASELINES))
def test_every_baseline_fits_applies_and_improves_on_the_5mm_score(name: str,
                                                                   frames: list) -> None:
    method = BASELINES[name](**SMALL.get(name, {})).fit(frames[:3])
    fr = frames[3]
    out = method.apply(fr.range_mm, fr.amplitude)
    assert out.dtype == np.float32 and out.shape == fr.range_mm.shape
    np.testing.assert_array_equal(np.isnan(out), np.isnan(fr.range_mm))
    hits_before, n = within_threshold(fr.range_mm, fr.reference_mm)
    hits_after, _ = within_threshold(out, fr.reference_mm)
    assert hits_after > hits_before, (hits_before / n, hits_after / n)


@pytest.mark.parametrize("name,function,params", [
    ("JBF", joint_bilateral, {"sigma_space": 1.5, "sigma_color": 0.05}),
    ("WMF", weighted_median, {"radius": 1, "sigma": 10.0}),
    ("TV", total_variation, {"lam": 0.5, "data": "l1"}),
])
def test_class_apply_equals_the_plain_function(name: str, function, params: dict,
                                               frames: list) -> None:
    fr = frames[0]
    np.testing.assert_array_equal(BASELINES[name]().apply(fr.range_mm, fr.amplitude, **params),
                                  function(fr.range_mm, fr.amplitude, **params))


def test_within_threshold_counts_nan_estimates_as_misses_and_skips_missing_reference() -> None:
    est = np.array([[100.0, 104.9, 105.0, np.nan]])
    ref = np.array([[100.0, 100.0, 100.0, 100.0]])
    assert within_threshold(est, ref) == (2.0, 4.0)
    ref[0, 0] = np.nan
    assert within_threshold(est, ref) == (1.0, 3.0)


def test_within_threshold_agrees_with_the_evaluation_metric(frames: list) -> None:
    from tof_mpd_ros.evaluation.metrics import accuracy_curve

    fr = frames[0]
    est = JBF().apply(fr.range_mm, fr.amplitude)
    hits, n = within_threshold(est, fr.reference_mm, 5.0)
    curve = accuracy_curve(est, fr.reference_mm, thresholds=(5.0,))
    assert n == curve.n_pixels and hits / n == pytest.approx(curve.accuracy[0], abs=1e-12)


def test_grid_search_picks_the_best_and_records_every_value(frames: list) -> None:
    grid = {"sigma_space": [0.5, 2.0], "sigma_color": [0.001, 0.2]}
    best, table = grid_search(JBF(), frames, grid)
    assert [row["params"] for row in table] == [
        {"sigma_space": s, "sigma_color": c} for s in (0.5, 2.0) for c in (0.001, 0.2)]
    scores = [row["score"] for row in table]
    assert best == table[int(np.argmax(scores))]["params"]
    assert best == {"sigma_space": 2.0, "sigma_color": 0.2}  # the strongest smoothing wins here
    # Scores are the pooled 5 mm fraction, recomputable by hand.
    hits = sum(within_threshold(JBF().apply(f.range_mm, f.amplitude, **best), f.reference_mm)[0]
               for f in frames)
    assert max(scores) == pytest.approx(hits / table[0]["n_pixels"])
    json.dumps({"best": best, "table": table})  # what the benchmark records


def test_grid_search_refits_over_fit_parameters(frames: list) -> None:
    method = RFWF(**SMALL["RF-WF"])
    _, table = grid_search(method, frames[2:], {"tau_mm": [1.0, 20.0], "sigma": [1.0]},
                              train_frames=frames[:2])
    assert [row["params"] for row in table] == [{"tau_mm": 1.0, "sigma": 1.0},
                                                {"tau_mm": 20.0, "sigma": 1.0}]
    assert table[0]["score"] != table[1]["score"]
    json.dumps(table)


def test_grid_search_works_on_tof_frames() -> None:
    fr = make_frame(np.random.default_rng(21))
    tof = ToFFrame(fr.range_mm, fr.amplitude, Intrinsics.from_fov(80, 60, 74.0),
                   reference_mm=fr.reference_mm)
    best, table = grid_search(PD(n_atoms=32), [tof], {"smoothness": [0.0, 1.0]})
    assert len(table) == 2 and best in [row["params"] for row in table]


def test_grid_search_rejects_bad_grids(frames: list) -> None:
    with pytest.raises(InputError, match="no parameter"):
        grid_search(JBF(), frames, {"sigma": [1.0]})
    with pytest.raises(InputError, match="non-empty list"):
        grid_search(JBF(), frames, {"sigma_space": []})
    with pytest.raises(InputError, match="train_frames"):
        grid_search(RFWF(), frames, {"tau_mm": [1.0]})
    no_ref = make_frame(np.random.default_rng(22))
    no_ref.reference_mm = None
    with pytest.raises(InputError, match="reference"):
        grid_search(JBF(), [no_ref], {"sigma_space": [1.0]})
