"""``tof-mpd evaluate`` and ``tof-mpd benchmark`` with a model of the fcn kind: its own stages
and method name (raw, calibrated, fcn), no F / G / edge numbers, the k-σ coverage of its
predicted σ, reports that say the kind; and the patch-only operations refuse it by name."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from benchmark_frames import H, W
from benchmark_frames import frames as _frames

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.correction.fcn import FCNCorrectionModel
from tof_mpd_ros.correction.pipeline import correct
from tof_mpd_ros.errors import InputError
from tof_mpd_ros.evaluation.benchmark import (
    BASELINE_NAMES,
    BenchmarkConfig,
    GridSpec,
    default_grids,
    run_benchmark,
)
from tof_mpd_ros.evaluation.components import evaluate_model, g_probabilities
from tof_mpd_ros.evaluation.metrics import SigmaCoverage
from tof_mpd_ros.evaluation.report import write_benchmark_report, write_component_report
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.training.edge_thresholds import choose_edge_thresholds, with_thresholds


@pytest.fixture(scope="module")
def fcn_model() -> FCNCorrectionModel:
    """An fcn model a few Adam steps into fitting the -6 mm offset (so its correction and σ
    are not the initial constants)."""
    model = FCNCorrectionModel.untrained(IntrinsicCalibration.identity(H, W), seed=0)
    from tof_mpd_ros.correction.fcn import fcn_inputs, gaussian_nll

    frames = _frames(7, 1, 2)
    r = np.stack([f.range_mm for f in frames])
    a = np.stack([f.amplitude for f in frames])
    target = torch.from_numpy(np.stack([f.reference_mm for f in frames]) - r)
    x, valid = fcn_inputs(r, a, model.architecture.multiple)
    mask = torch.from_numpy(valid) & torch.isfinite(target)
    optimiser = torch.optim.Adam(model.net.parameters(), lr=3e-3)
    model.net.train()
    for _ in range(15):
        corr, sigma = model.net(x, (H, W))
        loss = gaussian_nll(corr, sigma, target, mask)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    model.net.eval()
    return model


def _coverage_by_hand(model: FCNCorrectionModel, frames: list[ToFFrame]) -> list[float]:
    """Fraction of pixels with a σ and a reference whose |calibrated + correction - reference|
    is within k σ, k = 1, 2, 3, straight from ``correct``."""
    hits, n = np.zeros(3), 0
    for f in frames:
        out = correct(model, f.range_mm, f.amplitude)
        err = np.abs(out.range_f_mm.astype(np.float64) - f.reference_mm)
        scored = np.isfinite(err) & np.isfinite(out.sigma_mm)
        n += scored.sum()
        hits += [np.sum(scored & (err <= k * out.sigma_mm)) for k in (1, 2, 3)]
    return list(hits / n)


def test_evaluate_an_fcn_model_raw_calibrated_fcn_and_sigma_coverage(fcn_model, tmp_path
                                                                      ) -> None:
    frames = _frames(2, 1, 3)
    ev = evaluate_model(fcn_model, frames, n_examples=1)
    assert ev.kind == "fcn" and ev.final_stage == "fcn" and ev.n_frames == 3
    assert list(ev.stages) == ["raw", "calibrated", "fcn"]
    summary = ev.summary(5.0)
    for stage, row in summary.items():
        assert 0.0 <= row["whole"] <= 1.0 and 0.0 <= row["boundary"] <= 1.0, stage
        assert math.isfinite(row["mae_mm"]) and math.isfinite(row["rmse_mm"]), stage
    # the calibration is the identity here: calibrated = raw
    assert summary["calibrated"]["mae_mm"] == pytest.approx(summary["raw"]["mae_mm"])
    # the fcn stage is correct()'s range_mm, scored as any method (NaN = a miss)
    out = correct(fcn_model, frames[0].range_mm, frames[0].amplitude)
    err = np.abs(out.range_mm.astype(np.float64) - frames[0].reference_mm)
    one = evaluate_model(fcn_model, frames[:1]).stages["fcn"].whole
    scored = np.isfinite(frames[0].reference_mm)
    assert one.at(5.0) == pytest.approx(np.sum(scored & (err < 5.0)) / scored.sum())
    # no F, G or edges: absent, not made up
    assert ev.edges == {} and ev.g_operating_point == {}
    cov = ev.coverage
    assert cov["k"] == [1.0, 2.0, 3.0] and cov["pixels"] > 0.9 * 3 * H * W
    np.testing.assert_allclose(cov["observed"], _coverage_by_hand(fcn_model, frames), atol=1e-12)
    assert cov["observed"][0] <= cov["observed"][1] <= cov["observed"][2] <= 1.0
    np.testing.assert_allclose(cov["gaussian"], [0.682689, 0.954500, 0.997300], atol=1e-6)
    assert cov["median_sigma_mm"] > 0
    # regions by distance to the edges: the fcn kind's stages
    assert set(next(iter(ev.regions.values()))) == {"raw", "calibrated", "fcn"}

    data = json.loads(write_component_report(ev, tmp_path).read_text())
    assert data["model_kind"] == "fcn" and data["final_stage"] == "fcn"
    assert set(data["summary_5mm"]) == {"raw", "calibrated", "fcn"}
    assert data["sigma_coverage"]["observed"] == cov["observed"] and data["edges"] == {}
    page = (tmp_path / "index.html").read_text()
    assert "Model kind: <b>fcn</b>" in page and "k-σ coverage" in page
    assert "Not applicable: this model kind has no edge detector" in page
    assert not (tmp_path / "edges_precision_recall.png").exists()
    assert (tmp_path / "error_frame0_fcn.png").is_file()


def test_sigma_coverage_counts_within_k_sigma() -> None:
    est = np.array([[0.0, 1.0, 2.5, np.nan]])
    ref = np.zeros((1, 4))
    sigma = np.array([[1.0, 1.0, 1.0, 1.0]])
    tally = SigmaCoverage()
    tally.add(est, sigma, ref)
    tally.add(np.array([[3.5, 0.0, 0.0, 0.0]]), np.array([[1.0, np.nan, 1.0, 1.0]]), ref)
    out = tally.result()
    # scored: 0, 1, 2.5 | 3.5, 0, 0 -> within 1σ: 0, 1, 0, 0 (4 of 6); 2σ: +nothing; 3σ: +2.5
    assert out["pixels"] == 6
    np.testing.assert_allclose(out["observed"], [4 / 6, 4 / 6, 5 / 6])
    assert SigmaCoverage().result()["observed"] == [None, None, None]


def test_benchmark_with_an_fcn_model_lists_it_as_fcn(fcn_model, tmp_path) -> None:
    grids = {"JBF": GridSpec(grid={"sigma_space": [1.0, 2.0], "sigma_color": [0.1]}),
             "TV": GridSpec(grid={"lam": [0.2], "iterations": [30]})}
    config = BenchmarkConfig(grids=grids, n_examples=1, progress=False, profile_length_px=20)
    result = run_benchmark(fcn_model, _frames(1, 2, 2), _frames(3, 1, 2), config)
    assert result.kind == "fcn" and result.proposed == "fcn"
    assert list(result.methods) == ["raw", "calibrated", "JBF", "TV", "fcn"]
    table = result.table()
    for m, row in table.items():
        assert all(math.isfinite(v) for v in row.values()), m
    # the fcn row is the component analysis' fcn stage (the same frames, the same output)
    assert table["fcn"]["whole_5mm"] == pytest.approx(
        result.components.stages["fcn"].whole.at(5.0))
    assert result.components.coverage["pixels"] > 0
    write_benchmark_report(result, tmp_path)
    data = json.loads((tmp_path / "results.json").read_text())
    assert data["model_kind"] == "fcn" and data["proposed_method"] == "fcn"
    assert data["methods_order"] == ["raw", "calibrated", "JBF", "TV", "fcn"]
    assert data["diagnostics"]["ablation_reference_edges"] is None
    assert data["comparison"]["ranking_whole"][0] in data["methods_order"]
    assert set(data["comparison"]["targets"]) == {"fcn_beats_every_baseline_whole",
                                                   "fcn_beats_every_baseline_boundary"}
    assert "F" not in data["table"] and "proposed" not in data["table"]
    assert data["figures"]["edges"] == []
    page = (tmp_path / "index.html").read_text()
    assert "benchmarked as <b>fcn</b>" in page and 'class="proposed"><td>fcn</td>' in page
    # RFD keeps its own default encoding (an fcn model has no patch encoding)
    rfd = default_grids(fcn_model, quick=True)["RFD"]
    assert "encoding" not in rfd.init and set(default_grids(fcn_model)) == set(BASELINE_NAMES)


def test_patch_only_operations_refuse_an_fcn_model(fcn_model) -> None:
    f = _frames(4, 1, 1)[0]
    with pytest.raises(InputError, match=r"G's edge probabilities needs a model of the patch "
                                         r"kind.*kind 'fcn'"):
        g_probabilities(fcn_model, f.range_mm, f.amplitude)
    with pytest.raises(InputError, match=r"edge thresholds.*patch kind.*kind 'fcn'"):
        choose_edge_thresholds(fcn_model, [f])
    with pytest.raises(InputError, match=r"edge thresholds.*patch kind.*kind 'fcn'"):
        with_thresholds(fcn_model, None)
    # bfloat16 is not patch-only: the fcn kind runs its convolutions in it, close to float32
    low = correct(fcn_model, f.range_mm, f.amplitude, precision="bfloat16")
    ref = correct(fcn_model, f.range_mm, f.amplitude)
    ok = np.isfinite(ref.range_f_mm)
    assert np.nanmax(np.abs(low.range_f_mm - ref.range_f_mm)[ok]) < 0.5


def test_the_paper_comparison_judges_fcn_in_the_proposed_methods_place() -> None:
    from tof_mpd_ros.evaluation.benchmark import compare_with_paper

    acc = {"raw": (0.3, 0.2), "calibrated": (0.45, 0.3), "RFD": (0.7, 0.6), "TV": (0.5, 0.35),
           "fcn": (0.6, 0.5)}
    misses = {"clip_mm": None, "methods": {
        "fcn": {"miss_share": 0.4, "noise_limited": 0.2, "beyond_clip": None},
        "RFD": {"miss_share": 0.3, "noise_limited": 0.6, "beyond_clip": None}}}
    cmp = compare_with_paper(acc, {"misses": misses}, proposed="fcn")
    best = cmp["findings"][0]
    assert best["paper"] == "fcn (in the proposed method's place)" and best["ours"] == "RFD"
    assert best["why"].startswith("RFD is 10.0 points above fcn.")
    assert "Most of fcn's misses are bias" in best["why"]
    assert "truncation" not in best["why"] and "proposed method's misses" not in best["why"]
    assert cmp["targets"] == {"fcn_beats_every_baseline_whole": False,
                              "fcn_beats_every_baseline_boundary": False}
    with pytest.raises(InputError, match="needs raw, calibrated and fcn"):
        compare_with_paper({"raw": (0.1, 0.1), "calibrated": (0.2, 0.2)}, {}, proposed="fcn")
