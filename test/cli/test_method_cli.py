"""The method's commands end to end on tiny simulated NPZ files: calibrate, train, correct,
evaluate, sim predict — exit codes, files written, JSON numbers, one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from sim_helpers import looking_down, small_camera

from tof_mpd_ros.cli.main import main
from tof_mpd_ros.recordings import load_npz, save_npz
from tof_mpd_ros.sim.cell import SimCell
from tof_mpd_ros.sim.checkerboard import CheckerboardConfig, calibration_poses
from tof_mpd_ros.sim.scene import make_box_scene


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("cli")
    cell = SimCell(camera=small_camera())
    rng = np.random.default_rng(0)
    board = CheckerboardConfig(square_mm=120.0)
    captures = [cell.capture_checkerboard(p, rng, board=board, stamp_ns=i + 1)
                for i, p in enumerate(calibration_poses(60, rng))]
    scenes = [cell.capture(make_box_scene(yaw_rad=0.3 * i), looking_down(320.0 + 15 * i), rng,
                           stamp_ns=i + 1) for i in range(6)]
    paths = {"captures": out / "captures.npz", "train": out / "train.npz",
             "test": out / "test.npz", "dir": out}
    save_npz(paths["captures"], captures)
    save_npz(paths["train"], scenes[:4])
    save_npz(paths["test"], scenes[4:])
    return paths


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, dict | None, str]:
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    lines = [line for line in captured.out.splitlines() if line.startswith("{")]
    return code, json.loads(lines[-1]) if lines else None, captured.err


def test_calibrate_train_correct_evaluate(files: dict[str, Path],
                                          capsys: pytest.CaptureFixture[str]) -> None:
    d = files["dir"]
    code, out, _ = run(capsys, "calibrate", "intrinsic", files["captures"], "-o",
                       d / "calib.npz")
    assert code == 0 and out["rmse_after_mm"] < out["rmse_before_mm"]
    assert (d / "calib.json").is_file()

    code, out, _ = run(capsys, "train", files["train"], "--calibration", d / "calib.npz",
                       "-o", d / "w.npz", "--epochs", "2", "--max-samples-per-frame", "500",
                       "--target-clip-mm", "auto")
    assert code == 0 and out["epochs"] == 2 and (d / "w.npz").is_file()
    assert out["target_clip_mm"] >= 15.0  # from the data, never under the paper's
    chosen = out["edge_thresholds"]       # chosen on the validation frames
    assert chosen is not None and 0.0 <= chosen["low"] <= chosen["high"] <= 1.0
    history = json.loads((d / "w.json").read_text())["history"]
    assert np.isfinite(history[-1]["loss_range"])

    code, out, _ = run(capsys, "correct", files["test"], "-o", d / "corrected.npz",
                       "--weights", d / "w.npz")
    assert code == 0 and out["frames"] == 2
    corrected, raw = load_npz(d / "corrected.npz"), load_npz(files["test"])
    assert corrected[0].range_mm.shape == raw[0].range_mm.shape
    np.testing.assert_array_equal(corrected[0].reference_mm, raw[0].reference_mm)
    assert not np.array_equal(corrected[0].range_mm, raw[0].range_mm)

    code, out, _ = run(capsys, "evaluate", files["test"], "--weights", d / "w.npz", "-o",
                       d / "eval")
    assert code == 0 and out["n_frames"] == 2
    results = json.loads((d / "eval" / "results.json").read_text())
    assert set(results["stages"]) == {"raw", "calibrated", "F", "geodesic+G", "full"}
    assert (d / "eval" / "index.html").is_file()
    # the regions by distance to the edges split the whole image's scored pixels
    whole = results["stages"]["full"]["whole"]["n_pixels"]
    assert sum(r["full"]["pixels"] for r in results["regions"].values()) == whole
    point = results["g_operating_point"]
    assert 0.0 <= point["precision"] <= 1.0
    # per orientation: the reference edges of every group add up to all reference edges
    by = point["by_orientation"]
    assert set(by) == {"0°", "45°", "90°", "135°"}
    assert sum(g["n_gt"] for g in by.values()) == results["edges"]["G"]["n_gt"]
    # Calibration removes the simulated systematic error on these scenes.
    summary = results["summary_5mm"]
    assert summary["calibrated"]["whole"] > summary["raw"]["whole"]
    # the same networks in int8 score what float32 scores, and the file says which ran
    code, out, _ = run(capsys, "evaluate", files["test"], "--weights", d / "w.npz", "-o",
                       d / "eval8", "--precision", "int8")
    assert code == 0
    low = json.loads((d / "eval8" / "results.json").read_text())
    assert low["precision"] == "int8" and results["precision"] == "float32"
    for stage in ("F", "full"):
        assert abs(low["summary_5mm"][stage]["whole"] - summary[stage]["whole"]) < 0.005


def test_sim_predict_writes_the_same_kind_of_file(files: dict[str, Path],
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    out_path = files["dir"] / "predicted.npz"
    code, out, _ = run(capsys, "sim", "predict", files["test"], "-o", out_path)
    assert code == 0 and out["frames"] == 2
    real, predicted = load_npz(files["test"]), load_npz(out_path)
    valid = np.isfinite(real[0].range_mm) & np.isfinite(predicted[0].range_mm)
    assert valid.mean() > 0.8
    # The prediction from the reference tracks the full render within a few centimetres.
    assert np.median(np.abs(real[0].range_mm - predicted[0].range_mm)[valid]) < 15.0


def test_errors_are_one_line_and_exit_code_2(files: dict[str, Path],
                                             capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "correct", files["test"], "-o", files["dir"] / "x.npz",
                       "--weights", files["captures"])  # not a weights file
    assert code == 2 and len(err.strip().splitlines()) == 1 and "error" in err
    code, _, err = run(capsys, "evaluate", files["dir"] / "missing.npz", "-o",
                       files["dir"] / "e2")
    assert code == 2 and "no such file" in err
