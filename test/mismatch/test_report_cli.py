"""The report files, the command line and the benchmark's bookkeeping."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tof_mpd_ros.cli.main import main
from tof_mpd_ros.mismatch.benchmark import case_plan, parameter_error, summarise
from tof_mpd_ros.recordings import save_npz
from tof_mpd_ros.sim.tof import ToFConfig


@pytest.fixture(scope="module")
def drift_npz(tmp_path_factory, sweep):
    path = tmp_path_factory.mktemp("mm") / "real.npz"
    save_npz(path, sweep({"temperature_drift": {"max_mm": 8.0, "tau_frames": 5.0}}))
    return path


def test_mismatch_cli_writes_report(drift_npz, tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["mismatch", str(drift_npz), "-o", str(out), "--max-effects", "1"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["selected"] == ["temperature_drift"]
    doc = json.loads((out / "report.json").read_text())
    for key in ("selected", "ranking", "parameters", "rmse_before_mm", "rmse_after_mm"):
        assert key in doc
    assert doc["rmse_after_mm"] < doc["rmse_before_mm"]
    assert {r["effect"] for r in doc["ranking"]} >= {"multipath", "hand_eye", "noise_model"}
    assert all(r["evidence"] for r in doc["ranking"])
    cfg = ToFConfig.from_dict(json.loads((out / "fitted_config.json").read_text()))
    assert cfg.enabled("temperature_drift")
    html = (out / "index.html").read_text()
    for png in ("residual_histogram.png", "residual_images.png", "ranking.png"):
        assert (out / png).stat().st_size > 1000 and png in html


def test_mismatch_cli_errors_are_one_line(tmp_path, capsys):
    assert main(["mismatch", str(tmp_path / "missing.npz"), "-o", str(tmp_path / "o")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_monitoring_needs_the_config_of_an_earlier_run(drift_npz, tmp_path, capsys):
    assert main(["mismatch", str(drift_npz), "--workflow", "monitor", "-o",
                 str(tmp_path / "o")]) == 2
    assert "--workflow monitor needs --sim-config" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_case_plan_has_controls_singles_and_pairs():
    plan = case_plan(20, seed=3)
    assert len(plan) == 20
    assert sum(1 for p in plan if not p) == 4 and sum(1 for p in plan if len(p) == 2) == 3
    assert plan == case_plan(20, seed=3)


def test_scores_from_rows():
    rows = [
        {"truth": [], "selected": [], "top1": True, "both_found": None, "rmse_before_mm": 4.0,
         "rmse_after_mm": 4.0, "excess_before_mm": 1.0, "excess_after_mm": 1.0,
         "oracle_rmse_after_mm": 4.0, "parameter_error": {}},
        {"truth": [], "selected": ["wiggling"], "top1": False, "both_found": None,
         "rmse_before_mm": 4.0, "rmse_after_mm": 3.9, "excess_before_mm": 1.0,
         "excess_after_mm": 0.9, "oracle_rmse_after_mm": 4.0, "parameter_error": {}},
        {"truth": ["multipath"], "selected": ["multipath"], "top1": True, "both_found": None,
         "rmse_before_mm": 6.0, "rmse_after_mm": 4.5, "excess_before_mm": 2.0,
         "excess_after_mm": 0.5, "oracle_rmse_after_mm": 4.2,
         "parameter_error": {"multipath": 0.1}},
        {"truth": ["wiggling"], "selected": ["wiggling"], "top1": True, "both_found": None,
         "rmse_before_mm": 5.0, "rmse_after_mm": 4.0, "excess_before_mm": 2.0,
         "excess_after_mm": 0.5, "oracle_rmse_after_mm": 4.0, "parameter_error": {}},
    ]
    s = summarise(rows)
    assert s["false_alarm_rate"] == 0.5 and s["top1_accuracy_effect_cases"] == 1.0
    assert np.isclose(s["excess_rmse_cut_interior_mean"], 0.75)
    # cuts 0.25 and 0.2 against the oracle's 0.3 and 0.2: 0.45 of 0.5 achievable
    assert np.isclose(s["rmse_cut_mean"], 0.225) and np.isclose(s["rmse_cut_oracle_mean"], 0.25)
    assert np.isclose(s["rmse_cut_share_of_oracle"], 0.9)
    # |1.5 − 3| over the realistic range 0–5
    assert np.isclose(parameter_error("multipath", {"gain": 1.5}, {"gain": 3.0}), 0.3)


def test_benchmark_help_says_what_it_does(capsys):
    with pytest.raises(SystemExit):
        main(["mismatch-benchmark", "--help"])
    text = capsys.readouterr().out
    assert "labels.json" in text and "benchmark.json" in text and "min" in text


@pytest.mark.slow
def test_benchmark_runs_blind_and_scores(tmp_path):
    from tof_mpd_ros.mismatch import run_benchmark
    doc = run_benchmark(2, seed=5, out_dir=tmp_path, n_frames=4)
    assert (tmp_path / "labels.json").exists() and (tmp_path / "benchmark.txt").exists()
    assert len(list((tmp_path / "cases").glob("*.npz"))) == 2
    # each case's oracle is stored beside its answer: --merge scores an interrupted run
    assert len(list((tmp_path / "results").glob("*.oracle.json"))) == 2
    # the case files hold frames only: nothing names the concealed effect
    with np.load(tmp_path / "cases" / "case_000.npz") as npz:
        assert set(npz.files) <= {"range_mm", "amplitude", "reference_mm", "fx", "fy", "cx",
                                  "cy", "mod_freq_hz", "stamp_ns", "pose"}
    s = doc["summary"]
    for key in ("top1_accuracy", "false_alarm_rate", "parameter_error_median", "rmse_cut_mean",
                "rmse_cut_oracle_mean"):
        assert key in s
    for row in doc["cases"]:  # the oracle knows the truth: it never does worse than "before"
        assert row["oracle_rmse_after_mm"] <= row["rmse_before_mm"] + 0.05 or not row["truth"]


def test_recordings_work_like_npz(drift_npz, tmp_path):
    from tof_mpd_ros.mismatch import analyse, load_frames
    from tof_mpd_ros.recordings import import_npz
    import_npz(drift_npz, tmp_path / "rec")
    frames = load_frames(tmp_path / "rec")
    assert len(frames) == 6 and all(f.reference_mm is not None for f in frames)
    assert analyse(frames, max_effects=1).selected == ["temperature_drift"]


def test_oracle_config_is_nominal_plus_the_labels():
    from tof_mpd_ros.mismatch.cases import CONCEALABLE, draw_effect, truth_config
    rng = np.random.default_rng(0)
    effects = json.loads(json.dumps([{"name": n, "params": draw_effect(n, rng, 6)}
                                     for n in ("subsurface", "hand_eye")]))  # as in labels.json
    cfg = truth_config(effects)
    assert cfg.enabled("subsurface") and cfg.enabled("hand_eye")
    assert np.isclose(cfg.params("subsurface")["delay_mm"][0], effects[0]["params"]["delay_mm"][0])
    assert cfg.params("hand_eye")["rx_mrad"] == effects[1]["params"]["rx_mrad"]
    nominal = ToFConfig.nominal()
    assert [n for n in CONCEALABLE if cfg.enabled(n) != nominal.enabled(n)] == \
        [n for n in ("subsurface", "hand_eye") if not nominal.enabled(n)]
    assert truth_config([]).to_dict() == nominal.to_dict()


def test_another_camera_conceals_physics_not_its_own_values():
    """On a drawn camera the concealed effects are scene, pose and timing physics (less what a
    path tracer renders itself); the camera's values go to the label, the recording states the
    frequency, the amplitude is in the camera's units, and the oracle gets all of it."""
    from tof_mpd_ros.camera import Intrinsics
    from tof_mpd_ros.mismatch.cases import (
        PATHTRACE_OWN,
        PROFILE_FREQUENCIES_HZ,
        generate_case,
        truth_config,
    )
    from tof_mpd_ros.mismatch.profile import SCENE_EFFECTS
    assert all(set(p) <= set(SCENE_EFFECTS) for p in case_plan(30, 3, "profile"))
    plan = case_plan(30, 3, "pathtrace")
    assert all(not set(p) & set(PATHTRACE_OWN) for p in plan) and any(p for p in plan)
    case = generate_case(np.random.default_rng(5), ("lens_scatter",), n_frames=2,
                         intrinsics=Intrinsics.from_fov(24, 18, 74.0), base="profile")
    camera = case.labels["camera"]
    assert camera["mod_freq_hz"] in PROFILE_FREQUENCIES_HZ
    assert all(f.mod_freq_hz == camera["mod_freq_hz"] for f in case.frames)
    assert 0.01 <= camera["amplitude_scale"] <= 100.0
    oracle = truth_config(case.labels["effects"], camera)
    assert oracle.light_power == pytest.approx(ToFConfig.nominal().light_power
                                               * camera["amplitude_scale"])
    assert oracle.params("pixel_offset")["seed"] == camera["effects"]["pixel_offset"]["seed"]
    assert oracle.enabled("lens_scatter") and oracle.enabled("noise_model")
    # the materials the case's pixels see, for diagnostics: one map per frame, of the
    # library's materials, the table's diffuse one among them
    from tof_mpd_ros.sim.objects import MATERIAL_NAMES
    assert [m.shape for m in case.materials] == [f.range_mm.shape for f in case.frames]
    assert all(m.dtype == np.int32 for m in case.materials)
    assert set(np.unique(case.materials[0])) <= {-1, *MATERIAL_NAMES}
    assert (case.materials[0] == 0).mean() > 0.3
    with pytest.raises(ValueError):
        generate_case(np.random.default_rng(5), ("multipath",), base="pathtrace")


def test_camera_first_answers_are_not_rejudged_by_the_old_thresholds():
    from tof_mpd_ros.mismatch.benchmark import reselect
    old = {"selected": ["wiggling"], "parameters": {}, "metrics": {"rmse_before_mm": 5.0,
                                                                   "rmse_after_mm": 4.0},
           "ranking": [{"round": 1, "effect": "wiggling", "score": 3.0, "t": 1.0}]}
    assert reselect(old)["selected"] == []          # below today's threshold: none
    new = {**old, "selected": ["multipath"], "camera_profile": {"effects": []}}
    assert reselect(new) is new                      # round 1 there is the profile's


def test_benchmark_resume_runs_only_the_unanswered_cases(tmp_path, monkeypatch):
    """An interrupted run resumed: the answered cases are kept as they are, the others are made
    and answered; a directory made by another plan is refused, not mixed in."""
    from tof_mpd_ros.errors import MismatchError
    from tof_mpd_ros.mismatch import benchmark as bm

    made, answered = [], []
    metrics = {"rmse_before_mm": 10.0, "rmse_after_mm": 8.0,
               "interior_excess_rmse_before_mm": 4.0, "interior_excess_rmse_after_mm": 2.0}

    def generate(out, i, effects, seed, n_frames, base):
        made.append(i)
        return {"case": i, "file": f"cases/case_{i:03d}.npz", "base": base,
                "effects": [{"name": n, "params": {}} for n in effects]}

    monkeypatch.setattr(bm, "_generate_one", generate)
    monkeypatch.setattr(bm, "load_frames", lambda path: path)
    monkeypatch.setattr(bm, "analyse", lambda path: answered.append(path.name) or path)
    monkeypatch.setattr(bm, "to_json", lambda res: {"selected": [], "parameters": {},
                                                    "metrics": metrics,
                                                    "location": {"global": {}}})
    monkeypatch.setattr(bm, "oracle_metrics", lambda path, label: dict(metrics))
    monkeypatch.setattr(bm, "effect_visibility", lambda path, label: {})
    monkeypatch.setattr(bm, "refitted_visibility", lambda path, label: {})
    bm.run_benchmark(5, seed=3, out_dir=tmp_path)
    assert made == [0, 1, 2, 3, 4]
    (tmp_path / "results" / "case_003.oracle.json").unlink()  # interrupted before its oracle
    (tmp_path / "results" / "case_004.json").unlink()
    made.clear()
    answered.clear()
    doc = bm.run_benchmark(5, seed=3, out_dir=tmp_path, resume=True)
    assert made == [3, 4] and answered == ["case_003.npz", "case_004.npz"]
    assert len(doc["cases"]) == 5 and doc["cases_kept_from_earlier_run"] == 3
    with pytest.raises(MismatchError, match="--resume needs the same"):
        bm.run_benchmark(5, seed=4, out_dir=tmp_path, resume=True)


def test_visibility_of_a_concealed_effect_grows_with_its_strength(tmp_path, sweep):
    """A warm-up drift of 8 mm is worth far more than the tool's per-pixel threshold when known
    exactly; one of 0.05 mm (½(δ/σ)² ~ 0.1 mnats/px at the cell's ~2 mm noise) is not, after
    the penalty for its two parameters."""
    from tof_mpd_ros.mismatch.analysis import MIN_SCORE
    from tof_mpd_ros.mismatch.benchmark import effect_visibility

    seen = {}
    for max_mm in (8.0, 0.05):
        effect = {"temperature_drift": {"max_mm": max_mm, "tau_frames": 5.0}}
        path = tmp_path / f"drift_{max_mm}.npz"
        save_npz(path, sweep(effect))
        label = {"effects": [{"name": "temperature_drift", "params": effect["temperature_drift"]}]}
        seen[max_mm] = effect_visibility(path, label)["temperature_drift"]
    assert seen[8.0]["score_mnats"] > 10 * MIN_SCORE and seen[8.0]["t"] > 3.0
    assert seen[0.05]["score_mnats"] < 1.0


def test_top1_on_visible_and_faint_cases_apart():
    def row(truth, top1, vis):
        return {"truth": truth, "selected": truth if top1 else [], "top1": top1,
                "both_found": None, "rmse_before_mm": 5.0, "rmse_after_mm": 4.0,
                "excess_before_mm": 2.0, "excess_after_mm": 1.0, "oracle_rmse_after_mm": 4.0,
                "parameter_error": {}, "visibility_mnats": vis}
    s = summarise([row(["hand_eye"], True, 80.0), row(["multipath"], False, 40.0),
                   row(["time_offset"], False, 3.0), row([], True, None)])
    assert s["visible_effect_cases"] == 2
    assert s["top1_accuracy_visible_effect_cases"] == 0.5
    assert s["top1_accuracy_faint_effect_cases"] == 0.0


def test_benchmark_shards_share_one_plan_and_merge_into_it(tmp_path, monkeypatch):
    """Two shards of one plan make every case once between them (each case from its own seed,
    whatever its shard), and --merge scores them as one benchmark."""
    from tof_mpd_ros.mismatch import benchmark as bm
    from tof_mpd_ros.sim.dataset import Shard

    made = []
    metrics = {"rmse_before_mm": 10.0, "rmse_after_mm": 8.0,
               "interior_excess_rmse_before_mm": 4.0, "interior_excess_rmse_after_mm": 2.0}

    def generate(out, i, effects, seed, n_frames, base):
        made.append((out.name, i, effects))
        return {"case": i, "file": f"cases/case_{i:03d}.npz", "base": base,
                "effects": [{"name": n, "params": {}} for n in effects]}

    monkeypatch.setattr(bm, "_generate_one", generate)
    monkeypatch.setattr(bm, "load_frames", lambda path: path)
    monkeypatch.setattr(bm, "analyse", lambda path: path)
    monkeypatch.setattr(bm, "to_json", lambda res: {"selected": [], "parameters": {},
                                                    "metrics": metrics,
                                                    "location": {"global": {}},
                                                    "camera_profile": {"effects": []}})
    monkeypatch.setattr(bm, "oracle_metrics", lambda path, label: dict(metrics))
    monkeypatch.setattr(bm, "effect_visibility", lambda path, label: {})
    monkeypatch.setattr(bm, "refitted_visibility", lambda path, label: {})
    a = bm.run_benchmark(5, seed=3, out_dir=tmp_path / "a", shard=Shard(0, 2))
    b = bm.run_benchmark(5, seed=3, out_dir=tmp_path / "b", shard=Shard(1, 2))
    assert [i for d, i, _ in made if d == "a"] == [0, 2, 4]
    assert [i for d, i, _ in made if d == "b"] == [1, 3]
    plan = bm.case_plan(5, 3, "nominal")
    assert all(effects == plan[i] for _, i, effects in made)
    assert len(a["cases"]) == 3 and len(b["cases"]) == 2
    merged = bm.merge_runs([tmp_path / "a", tmp_path / "b"], tmp_path / "m")
    assert sorted(r["case"] for r in merged["cases"]) == ["a/0", "a/2", "a/4", "b/1", "b/3"]
    assert merged["summary"]["cases"] == 5


def test_benchmark_cli_refuses_a_bad_shard(tmp_path):
    from tof_mpd_ros.cli.main import main

    assert main(["mismatch-benchmark", "--shard", "2/2", "-o", str(tmp_path / "x")]) != 0
    assert not (tmp_path / "x").exists()


def test_truth_margin_is_zero_for_the_truth_and_large_for_a_missed_drift(tmp_path, sweep):
    """The data prefer the true model to an answer that missed an 8 mm warm-up drift by far
    more than the tool's threshold (the level free does not take a drift's change from frame
    to frame); an answer equal to the truth has no margin."""
    from tof_mpd_ros.mismatch.analysis import MIN_SCORE
    from tof_mpd_ros.mismatch.benchmark import truth_margin
    from tof_mpd_ros.mismatch.cases import truth_config

    params = {"max_mm": 8.0, "tau_frames": 5.0}
    path = tmp_path / "drift.npz"
    save_npz(path, sweep({"temperature_drift": params}))
    label = {"effects": [{"name": "temperature_drift", "params": params}]}
    found = truth_margin(path, label, {"config_after": truth_config(label["effects"]).to_dict()})
    missed = truth_margin(path, label, {"config_after": ToFConfig.nominal().to_dict()})
    assert abs(found) < 1.0
    assert missed > 5 * MIN_SCORE
    assert truth_margin(path, label, {"selected": []}) is None


def test_top1_on_decidable_cases_leaves_out_the_ties_of_the_likelihood():
    def row(truth, top1, margin):
        return {"truth": truth, "selected": truth if top1 else [], "top1": top1,
                "both_found": None, "rmse_before_mm": 5.0, "rmse_after_mm": 4.0,
                "excess_before_mm": 2.0, "excess_after_mm": 1.0, "oracle_rmse_after_mm": 4.0,
                "parameter_error": {}, "visibility_mnats": 50.0, "truth_margin_mnats": margin}
    s = summarise([row(["hand_eye"], True, 0.5), row(["multipath"], False, 40.0),
                   row(["lens_scatter"], False, 3.0), row(["subsurface"], False, -20.0),
                   row(["time_offset"], True, None), row([], True, 0.0)])
    assert s["effect_cases_with_truth_margin"] == 4
    assert s["decidable_effect_cases"] == 2          # the right answer and the 40 mnats miss
    assert s["top1_accuracy_decidable_effect_cases"] == 0.5
    assert s["misses_the_truth_fits_no_better"] == 2
    assert s["effect_cases_with_refitted_visibility"] == 2      # the two right answers


def test_nameable_cases_count_only_effects_that_pay_over_the_refitted_camera():
    """A miss whose truth leads the answer (40 mnats/px) but whose effect pays nothing over
    the camera refitted from the truth is a tie of the model, not a nameable miss."""
    def row(top1, margin, refitted):
        return {"truth": ["hand_eye"], "selected": ["hand_eye"] if top1 else [], "top1": top1,
                "both_found": None, "rmse_before_mm": 5.0, "rmse_after_mm": 4.0,
                "excess_before_mm": 2.0, "excess_after_mm": 1.0, "oracle_rmse_after_mm": 4.0,
                "parameter_error": {}, "visibility_mnats": 50.0, "truth_margin_mnats": margin,
                "refitted_visibility_mnats": refitted}
    s = summarise([row(True, 0.5, 3.0), row(False, 40.0, -1.8), row(False, 5.0, 30.0),
                   row(False, 40.0, None), row(True, 20.0, None)])
    assert s["decidable_effect_cases"] == 4           # by the truth's margin
    # the unmeasured miss is left out; a right answer counts unmeasured, as nameable
    assert s["effect_cases_with_refitted_visibility"] == 4
    assert s["nameable_effect_cases"] == 3            # the two hits and the 30 mnats/px miss
    assert s["top1_accuracy_nameable_effect_cases"] == 2 / 3
    assert s["misses_the_camera_absorbs"] == 1


def test_refitted_visibility_pays_for_a_drift_and_not_for_an_effect_that_is_absent(tmp_path,
                                                                                    sweep):
    """An 8 mm warm-up drift moves the frames' levels apart, which no camera profile takes:
    it pays far over the threshold with the profile refitted from the truth. A time offset
    claimed by a label but absent from the frames pays nothing (held at its claimed value it
    costs; fitted from there it can only take noise, below its penalty)."""
    from tof_mpd_ros.mismatch.analysis import MIN_SCORE
    from tof_mpd_ros.mismatch.benchmark import refitted_visibility

    params = {"max_mm": 8.0, "tau_frames": 5.0}
    path = tmp_path / "drift.npz"
    save_npz(path, sweep({"temperature_drift": params}))
    drift = {"name": "temperature_drift", "params": params}
    found = refitted_visibility(path, {"effects": [drift]})["temperature_drift"]
    assert found["score_mnats"] > 5 * MIN_SCORE
    assert found["score_mnats"] == max(found["held_mnats"], found["fitted_mnats"])
    absent = {"name": "time_offset", "params": {"offset_ms": 30.0}}
    claimed = refitted_visibility(path, {"effects": [drift, absent]})
    assert claimed["time_offset"]["score_mnats"] < MIN_SCORE
    assert claimed["time_offset"]["held_mnats"] < claimed["time_offset"]["fitted_mnats"]
    assert refitted_visibility(path, {"effects": []}) == {}


def test_the_verdict_says_when_the_model_leaves_something_unexplained():
    """An empty answer with misfits is not "no significant mismatch" (ADI mode 3 of session 32
    named nothing and left 13.9 mm RMSE with a refused interreflection gain); a fit inside the
    camera's own window is no misfit; each effect and case is said once."""
    from tof_mpd_ros.mismatch.analysis import Analysis
    from tof_mpd_ros.mismatch.report import misfits, to_json

    nominal = ToFConfig.nominal()

    def verdict(selected, unexplained):
        a = Analysis(selected, [], {}, nominal, nominal, {}, {}, [])
        a.unexplained = unexplained
        return to_json(a)["verdict"]

    signature = {"effect": "multipath", "case": "signature"}
    edge = {"effect": "noise_model", "case": "profile_edge"}
    window = {"effect": "multipath", "case": "camera_window"}
    assert verdict([], []) == "none: no significant mismatch"
    assert verdict([], [window]) == "none: no significant mismatch"
    assert verdict([], [signature, edge, signature]) == (
        "none named; the model does not explain all of the residual: multipath (signature), "
        "noise_model (profile edge)")
    assert verdict(["mixed_pixels", "multipath"], []) == "mixed_pixels, multipath"
    assert verdict(["mixed_pixels"], [window, edge]) == (
        "mixed_pixels; the model does not explain all of the residual: noise_model (profile "
        "edge)")
    assert misfits([window, edge]) == [edge]


def test_merged_rows_tell_runs_of_two_seeds_apart(tmp_path):
    """Shard directories of two seeds share their names (``s1/0``, ``s2/0``): the merged rows
    carry as much of the path as tells them apart, and only that much."""
    from tof_mpd_ros.mismatch.benchmark import _run_names

    dirs = [tmp_path / "s1" / "0", tmp_path / "s2" / "0", tmp_path / "s2" / "1"]
    assert _run_names(dirs) == ["s1/0", "s2/0", "s2/1"]
    assert _run_names(dirs[1:]) == ["0", "1"]
    assert _run_names([dirs[0], dirs[0]]) == [str(dirs[0].resolve())] * 2


def test_merge_names_a_path_that_is_not_a_run_instead_of_crashing(tmp_path):
    """``--merge dir/*`` also matches the runs' ``.log`` files: the error names them."""
    from tof_mpd_ros.errors import MismatchError
    from tof_mpd_ros.mismatch.benchmark import merge_runs

    log = tmp_path / "0.log"
    log.write_text("benchmark cases: 100%\n")
    with pytest.raises(MismatchError, match=r"not a benchmark directory.*0\.log"):
        merge_runs([log], tmp_path / "out")
    assert not (tmp_path / "out").exists()
