"""``tof-mpd benchmark``: a tiny end-to-end run (every method, every file), the session split,
the ranking and its comparison with the paper, the profile line and the HTML report."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from benchmark_frames import HOUR_NS, H, W
from benchmark_frames import frames as _frames

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.correction.encoding import EncodingConfig
from tof_mpd_ros.correction.pipeline import CorrectionModel
from tof_mpd_ros.errors import InputError
from tof_mpd_ros.evaluation.benchmark import (
    BASELINE_NAMES,
    METHODS,
    BenchmarkConfig,
    GridSpec,
    compare_with_paper,
    rank_methods,
    run_benchmark,
    session_groups,
    split_train_val,
)
from tof_mpd_ros.evaluation.profiles import choose_boundary_line, sample_profile
from tof_mpd_ros.evaluation.report import write_benchmark_report
from tof_mpd_ros.frame import ToFFrame


def _model() -> CorrectionModel:
    calib = IntrinsicCalibration(np.full((H, W), -6.0), np.ones((H, W)), np.zeros((H, W)),
                                 np.ones((H, W), bool))
    enc = EncodingConfig(range_min_mm=300.0, range_max_mm=450.0, amplitude_min=0.2,
                         amplitude_max=2.0)
    return CorrectionModel.untrained(calib, enc, seed=0)


def _tiny_grids(model: CorrectionModel) -> dict[str, GridSpec]:
    small_forest = {"n_estimators": 3, "max_depth": 6, "samples_per_frame": 300}
    return {
        "JBF": GridSpec(grid={"sigma_space": [1.0, 2.0], "sigma_color": [0.1]}),
        "WMF": GridSpec(grid={"radius": [1], "sigma": [25.5]}),
        "RF-WF": GridSpec(init=small_forest, grid={"sigma": [1.0], "power": [1.0, 2.0]}),
        "RFD": GridSpec(init={"encoding": model.encoding, **small_forest},
                        grid={"max_depth": [4, 6], "n_trees": [0]}),
        "TV": GridSpec(grid={"lam": [0.2], "iterations": [40]}),
        "PD": GridSpec(init={"n_atoms": 16}, grid={"smoothness": [1.0], "iterations": [2]}),
    }


@pytest.fixture(scope="module")
def bench_run(tmp_path_factory: pytest.TempPathFactory):
    model = _model()
    config = BenchmarkConfig(grids=_tiny_grids(model), n_examples=2, progress=False,
                             profile_length_px=20)
    test = _frames(2, 1, 3)
    test.append(ToFFrame(test[0].range_mm, test[0].amplitude, test[0].intrinsics))  # no ref
    result = run_benchmark(model, _frames(1, 3, 2), test, config)
    out = tmp_path_factory.mktemp("bench")
    write_benchmark_report(result, out, extra={"note": "tiny"})
    return result, out


def test_end_to_end_every_method_and_file(bench_run) -> None:
    _, out = bench_run
    data = json.loads((out / "results.json").read_text())
    assert data["methods_order"] == list(METHODS)
    assert set(data["methods"]) == set(METHODS) == set(data["table"])
    assert data["n_test_frames"] == 3 and data["n_test_frames_without_reference"] == 1
    for m in METHODS:
        row = data["table"][m]
        for key in ("whole_2mm", "whole_5mm", "whole_10mm", "boundary_2mm", "boundary_5mm",
                    "boundary_10mm", "mae_mm", "ms_per_frame"):
            assert row[key] is not None, (m, key)
        assert 0.0 <= row["whole_5mm"] <= 1.0
    assert data["table"]["raw"]["ms_per_frame"] == 0.0
    # Baselines: fitted on two sessions, searched on the third; grids and choices recorded.
    assert data["split"]["how"] == "sessions" and len(data["split"]["val_frames"]) == 2
    for name in BASELINE_NAMES:
        b = data["baselines"][name]
        assert b["chosen"] and b["table"] and b["grid_searched"]
        assert b["n_combinations"] == len(b["table"])
        assert b["n_fit_frames"] == 4 and b["n_val_frames"] == 2
    assert data["baselines"]["RFD"]["n_combinations"] == 2            # refit per max_depth
    assert "max_depth" in data["baselines"]["RFD"]["chosen"]
    assert data["baselines"]["RFD"]["init"]["encoding"]["range_min_mm"] == 300.0
    assert set(data["components"]["stages"]) == {"raw", "calibrated", "F", "geodesic+G", "full"}
    assert set(data["components"]["edges"]) == {"G", "Canny (raw ToF)"}
    cmp = data["comparison"]
    assert sorted(cmp["ranking_whole"]) == sorted(m for m in METHODS if m != "F")
    assert cmp["statement"].startswith("Ranking at 5 mm")
    assert data["note"] == "tiny" and len(data["examples"]) == 2
    # The measurements behind the findings: the regions partition the scored pixels (their
    # pooled accuracy is the table's), every method's misses are tallied, and the ablation
    # with the reference's edges ran.
    regions = data["diagnostics"]["regions_within_5mm"]
    for m in (*METHODS, "full, reference edges"):
        hits = sum(r[m]["within"] * r[m]["pixels"] for r in regions.values())
        pixels = sum(r[m]["pixels"] for r in regions.values())
        if m in data["table"]:
            assert hits / pixels == pytest.approx(data["table"][m]["whole_5mm"], abs=1e-9)
    misses = data["diagnostics"]["misses"]
    assert set(misses["methods"]) == set(METHODS) and misses["clip_mm"] > 0
    assert 0.0 <= data["diagnostics"]["ablation_reference_edges"]["whole"]["accuracy"][0] <= 1
    # The calibration (-6 mm) removes the offset: calibrated beats raw.
    assert data["table"]["calibrated"]["whole_5mm"] > data["table"]["raw"]["whole_5mm"]
    files = {p.name for p in out.iterdir()}
    assert {"accuracy_whole.png", "accuracy_boundary.png", "edges_precision_recall.png",
            "accuracy_components.png", "qualitative_frame0.png", "qualitative_frame1.png",
            "index.html", "results.json"} <= files
    assert any(name.startswith("profile_frame") for name in files)


def test_html_references_every_png_and_states_the_ranking(bench_run) -> None:
    _, out = bench_run
    page = (out / "index.html").read_text()
    pngs = {p.name for p in out.glob("*.png")}
    assert pngs and pngs == set(re.findall(r'src="([^"]+\.png)"', page))
    assert "Ranking at 5 mm" in page and "RFD 2nd" in page
    for m in METHODS:
        assert f"<td>{m}</td>" in page
    assert json.loads((out / "results.json").read_text())["figures"]["curves"] == [
        "accuracy_whole.png", "accuracy_boundary.png"]


def test_session_split() -> None:
    stamps = [0, 1, 2, HOUR_NS, HOUR_NS + 1, 2 * HOUR_NS, 2 * HOUR_NS + 1, 3 * HOUR_NS]
    assert session_groups(stamps) == [0, 0, 0, 1, 1, 2, 2, 3]
    assert session_groups([0, 1, 2], sources=[0, 0, 1]) == [0, 0, 1]
    split = split_train_val(stamps, 0.25)
    assert split.how == "sessions" and split.n_groups == 4
    assert split.val == (7,) and split.fit == (0, 1, 2, 3, 4, 5, 6)
    split = split_train_val(stamps, 0.5)
    assert set(split.val) == {3, 4, 7} and not set(split.val) & set(split.fit)
    split = split_train_val([0, 1, 2, 3, 4, 5, 6, 7], 0.25)     # one session: the tail
    assert split.how == "tail" and split.val == (6, 7)
    split = split_train_val(list(range(20)), 0.5, max_val_frames=3)
    assert split.val == (10, 14, 19) and len(split.fit) == 10
    with pytest.raises(InputError, match="at least 2"):
        split_train_val([0], 0.25)


def test_rank_methods_orders_by_whole_then_boundary_then_mae() -> None:
    whole = {"a": 0.5, "b": 0.7, "c": 0.7, "d": float("nan")}
    boundary = {"a": 0.9, "b": 0.3, "c": 0.4, "d": 0.9}
    assert rank_methods(whole, boundary) == ["c", "b", "a", "d"]
    boundary["b"] = 0.4
    assert rank_methods(whole, boundary, {"b": 1.0, "c": 2.0}) == ["b", "c", "a", "d"]


def _acc(**scores: tuple[float, float]) -> dict[str, tuple[float, float]]:
    base = {"raw": (0.30, 0.20), "calibrated": (0.45, 0.30), "JBF": (0.47, 0.31),
            "WMF": (0.47, 0.32), "RF-WF": (0.48, 0.33), "RFD": (0.55, 0.40),
            "TV": (0.46, 0.31), "PD": (0.46, 0.30), "F": (0.60, 0.42), "proposed": (0.63, 0.50)}
    return {**base, **scores}


def test_comparison_agrees_with_the_paper_when_the_ranking_matches() -> None:
    cmp = compare_with_paper(_acc(), {})
    assert cmp["ranking_whole"][:2] == ["proposed", "RFD"]
    assert all(f["agrees"] and f["why"] is None for f in cmp["findings"])
    assert cmp["targets"] == {"proposed_beats_every_baseline_whole": True,
                              "proposed_beats_every_baseline_boundary": True}


def test_comparison_explains_a_smoother_ranked_above_rfd() -> None:
    regions = {"edge (<= 2 px)": {"calibrated": {"within": 0.30}, "PD": {"within": 0.20}},
               "interior (> 5 px)": {"calibrated": {"within": 0.50}, "PD": {"within": 0.49}}}
    evidence = {"noise_share": 0.6, "noise_rms_mm": 4.0, "bias_rms_mm": 3.0,
                "rfd_training_pixels": 20_000, "val_scores": {"PD": 0.40},
                "val_calibrated": 0.45, "boundary_share": 0.2, "regions": regions}
    cmp = compare_with_paper(_acc(TV=(0.58, 0.35), PD=(0.44, 0.25)), evidence)
    assert cmp["ranking_whole"][:3] == ["proposed", "TV", "RFD"]
    second = next(f for f in cmp["findings"] if f["aspect"].startswith("second"))
    assert not second["agrees"] and second["ours"] == "TV"
    assert second["why"].startswith("RFD is 3rd") and "TV" in second["why"]
    assert "60.0 %" in second["why"] and "20,000" in second["why"]
    below = next(f for f in cmp["findings"] if f["aspect"].startswith("every baseline"))
    assert below["aspect"].endswith("whole image")
    assert not below["agrees"] and "PD" in below["ours"]
    assert "even on the validation frames" in below["why"]
    below_b = next(f for f in cmp["findings"]
                   if f["aspect"] == "every baseline improves on the calibrated range, "
                                     "boundary region")
    assert not below_b["agrees"] and "PD" in below_b["ours"]
    # the measured reason: 10 points lost on the edges, 1 in the interior
    assert "-10.0 points within 2 px" in below_b["why"] and "-1.0 points beyond" in \
        below_b["why"] and "loses on the edges themselves" in below_b["why"]
    second_b = next(f for f in cmp["findings"] if f["aspect"] == "second at 5 mm, boundary "
                                                                 "region")
    assert second_b["agrees"] and second_b["why"] is None     # RFD 0.40 > TV 0.35
    assert cmp["statement"].index("TV (") < cmp["statement"].index("RFD (")


def test_comparison_flags_a_baseline_beating_the_method() -> None:
    cmp = compare_with_paper(_acc(RFD=(0.70, 0.55)),
                             {"f_training_patches": 500_000, "f_epochs": 3})
    first = cmp["findings"][0]
    assert not first["agrees"] and first["ours"] == "RFD" and "500,000" in first["why"]
    second = next(f for f in cmp["findings"] if f["aspect"].startswith("second"))
    assert second["ours"] == "proposed" and second["why"].startswith("RFD ranks 1st")
    f_vs_rfd = next(f for f in cmp["findings"] if f["aspect"].startswith("F alone"))
    assert not f_vs_rfd["agrees"] and "500,000" in f_vs_rfd["why"]
    assert cmp["targets"]["proposed_beats_every_baseline_whole"] is False
    assert cmp["targets"]["proposed_beats_every_baseline_boundary"] is False
    with pytest.raises(InputError):
        compare_with_paper({"raw": (0.1, 0.1)}, {})


def _misses(noisy: float, beyond: float) -> dict:
    return {"clip_mm": 15.0, "beyond_share": 0.1,
            "methods": {m: {"misses": 100, "miss_share": 0.3, "noise_limited": noisy,
                            "beyond_clip": beyond} for m in ("proposed", "F", "RFD")}}


@pytest.mark.parametrize("noisy,beyond,lever", [
    (0.1, 0.7, "out of its reach"), (0.7, 0.1, "noise-limited: the local mean"),
    (0.2, 0.2, "distortion F did not learn")])
def test_a_forest_ahead_is_explained_by_what_the_misses_are_made_of(noisy, beyond, lever):
    cmp = compare_with_paper(_acc(RFD=(0.70, 0.55)), {"misses": _misses(noisy, beyond)})
    why = cmp["findings"][0]["why"]
    assert lever in why and f"{100 * beyond:.1f} % beyond ±15 mm" in why
    assert "forest matches a small network" not in why   # no unmeasured reasons


@pytest.mark.parametrize("oracle,cause", [((0.64, 0.47), "G's edge map is what costs"),
                                          ((0.58, 0.40), "the filter itself")])
def test_geodesic_step_below_f_is_explained_by_the_reference_edge_ablation(oracle, cause):
    cmp = compare_with_paper(_acc(F=(0.62, 0.45), proposed=(0.63, 0.41)),
                             {"reference_edges": oracle})
    finding = next(f for f in cmp["findings"] if f["aspect"].startswith("geodesic filtering"))
    assert not finding["agrees"] and cause in finding["why"]
    assert f"{100 * oracle[1]:.1f} %" in finding["why"]


def test_choice_at_the_grid_edge_is_flagged() -> None:
    from tof_mpd_ros.evaluation.baselines import JBF, RFD
    from tof_mpd_ros.evaluation.benchmark import TunedBaseline

    spec = GridSpec(grid={"sigma_space": [1.0, 2.0, 3.0], "sigma_color": [0.05, 0.1, 0.2],
                          "diameter": [0, 5]})
    tb = TunedBaseline("JBF", JBF(), {}, {"sigma_space": 1.0, "sigma_color": 0.1,
                                          "diameter": 5}, spec, [], 0.5, 0.0, 0.0, 1, 1)
    assert tb.at_grid_edge() == ["sigma_space"]
    assert tb.to_dict()["chosen_at_grid_edge"] == ["sigma_space"]
    rfd = TunedBaseline("RFD", RFD(), {}, {"n_trees": 0}, GridSpec(grid={"n_trees": [10, 20, 0]}),
                        [], 0.5, 0.0, 0.0, 1, 1)
    assert rfd.at_grid_edge() == []


def test_profile_line_crosses_one_boundary_mid_line() -> None:
    ref = np.full((30, 40), 400.0)
    ref[10:20, 15:40] = 330.0
    line = choose_boundary_line(ref, length_px=12)
    assert line is not None and abs(line.step_mm - 70.0) < 1e-6
    prof = sample_profile(ref, line)
    assert prof.shape == (12,) and {prof[0], prof[-1]} == {400.0, 330.0}
    assert choose_boundary_line(np.full((30, 40), 400.0)) is None
    with pytest.raises(InputError):
        sample_profile(np.zeros((5, 5)), line)


def test_config_rejects_bad_settings() -> None:
    with pytest.raises(InputError, match="val_fraction"):
        BenchmarkConfig(val_fraction=1.0)
    with pytest.raises(InputError, match="unknown baselines"):
        BenchmarkConfig(grids={"XYZ": GridSpec()})
    with pytest.raises(InputError, match="thresholds"):
        BenchmarkConfig(thresholds=(1.0, 2.0))


def test_cli_benchmark_on_npz(tmp_path: Path) -> None:
    from tof_mpd_ros.cli.main import main
    from tof_mpd_ros.correction.weights import save_weights
    from tof_mpd_ros.recordings import save_npz

    save_npz(tmp_path / "train.npz", _frames(5, 2, 2))
    save_npz(tmp_path / "test.npz", _frames(6, 1, 1))
    save_weights(tmp_path / "w.npz", _model())
    argv = ["benchmark", "--train", str(tmp_path / "train.npz"), "--test",
            str(tmp_path / "test.npz"), "--weights", str(tmp_path / "w.npz"), "-o",
            str(tmp_path / "out"), "--quick", "--methods", "JBF,WMF", "--examples", "1",
            "--no-progress"]
    assert main(argv) == 0
    data = json.loads((tmp_path / "out" / "results.json").read_text())
    assert set(data["baselines"]) == {"JBF", "WMF"}
    assert data["weights"].endswith("w.npz") and (tmp_path / "out" / "index.html").is_file()
    assert main([*argv[:-3], "--methods", "JBF,XYZ"]) == 2


def test_demo_summary_prints_the_ranking_and_differences(capsys: pytest.CaptureFixture,
                                                         tmp_path: Path) -> None:
    from tof_mpd_ros.cli.demo import _print_summary

    cmp = compare_with_paper(_acc(TV=(0.58, 0.35)), {"noise_share": 0.5})
    row = {"whole": 0.5, "boundary": 0.4, "mae_mm": 3.0, "ms_per_frame": 10.0}
    _print_summary({"weights": "shipped", "n_test_frames": 3, "ms_per_frame": 12.0,
                    "summary_5mm": {"raw": row, "proposed": row},
                    "ranking_statement": cmp["statement"],
                    "differences_from_paper": [f for f in cmp["findings"] if not f["agrees"]],
                    "targets": cmp["targets"], "edges_max_f1": {"G": 0.9}}, tmp_path)
    out = capsys.readouterr().out
    assert "Ranking at 5 mm" in out and "differs from the paper (second at 5 mm" in out
    assert "proposed_beats_every_baseline_whole: met" in out


def test_the_stages_go_through_the_one_component_loop(bench_run, monkeypatch) -> None:
    """The benchmark's component analysis is ``tof-mpd evaluate``'s: the same numbers on the
    same frames, from :class:`ComponentTally` (one ``add`` per test frame with a reference)."""
    from tof_mpd_ros.evaluation import components

    result, _ = bench_run
    alone = components.evaluate_model(_model(), _frames(2, 1, 3)).to_dict()
    ours = result.components.to_dict()
    for key in ("n_frames", "stages", "edges", "summary_5mm", "relative_improvement_5mm"):
        assert ours[key] == alone[key], key
    assert alone["regions"] and alone["g_operating_point"]      # evaluate's diagnostics
    assert ours["regions"] == {} and ours["g_operating_point"] == {}   # as before the merge

    frames: list[int] = []
    add = components.ComponentTally.add
    monkeypatch.setattr(components.ComponentTally, "add",
                        lambda self, *args: frames.append(1) or add(self, *args))
    grids = {"JBF": GridSpec(grid={"sigma_space": [1.0], "sigma_color": [0.1]})}
    run_benchmark(_model(), _frames(1, 2, 1), _frames(3, 1, 2),
                  BenchmarkConfig(grids=grids, n_examples=0, progress=False))
    assert len(frames) == 2
