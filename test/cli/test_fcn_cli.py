"""``tof-mpd correct`` and ``tof-mpd evaluate`` with weights of the fcn kind: the NPZ written holds
the predicted σ beside the corrected range (a recording directory has no room for it and says
so), and evaluate reports the kind and the σ coverage."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.cli.main import main
from tof_mpd_ros.correction.fcn import FCNCorrectionModel
from tof_mpd_ros.correction.pipeline import correct
from tof_mpd_ros.correction.weights import save_weights
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.recordings import iter_frames, save_npz

H, W = 16, 32


def _frames() -> list[ToFFrame]:
    rng = np.random.default_rng(3)
    out = []
    for i in range(2):
        truth = 450.0 + np.zeros((H, W)) + 0.5 * np.arange(W)
        truth[4:10, 8:20] -= 60.0
        measured = truth + 5.0 + rng.normal(0, 1.5, truth.shape)
        measured[0, 0] = np.nan
        out.append(ToFFrame(measured.astype(np.float32), np.full((H, W), 0.7, np.float32),
                            Intrinsics.from_fov(W, H, 60.0), reference_mm=truth.astype(np.float32),
                            stamp_ns=i + 1))
    return out


@pytest.fixture(scope="module")
def paths(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("fcn_cli")
    model = FCNCorrectionModel.untrained(IntrinsicCalibration.identity(H, W), seed=2)
    weights = save_weights(d / "fcn.npz", model)
    frames = d / "frames.npz"
    save_npz(frames, _frames())
    return {"dir": d, "weights": weights, "frames": frames}


def _run(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, dict]:
    code = main([str(a) for a in argv])
    lines = [x for x in capsys.readouterr().out.splitlines() if x.startswith("{")]
    return code, json.loads(lines[-1])


def test_correct_writes_sigma_into_an_npz_and_says_a_recording_has_none(
        paths: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    from tof_mpd_ros.correction.weights import load_weights

    out_npz = paths["dir"] / "corrected.npz"
    code, summary = _run(capsys, "correct", paths["frames"], "-o", out_npz,
                         "--weights", paths["weights"])
    assert code == 0 and summary["model_kind"] == "fcn" and summary["sigma_mm_written"]
    model = load_weights(paths["weights"])
    with np.load(out_npz) as data:
        sigma, corrected = data["sigma_mm"], data["range_mm"]
    assert sigma.shape == corrected.shape == (2, H, W) and sigma.dtype == np.float32
    for i, frame in enumerate(_frames()):
        expected = correct(model, frame.range_mm, frame.amplitude)
        np.testing.assert_allclose(sigma[i], expected.sigma_mm, rtol=1e-6, equal_nan=True)
        np.testing.assert_allclose(corrected[i], expected.range_mm, rtol=1e-6, equal_nan=True)
    assert np.isnan(sigma[:, 0, 0]).all() and np.isfinite(sigma[:, 1:, 1:]).all()
    assert np.nanmin(sigma) > 0

    out_dir = paths["dir"] / "corrected_rec"
    code, summary = _run(capsys, "correct", paths["frames"], "-o", out_dir,
                         "--weights", paths["weights"])
    assert code == 0 and summary["frames"] == 2 and summary["sigma_mm_written"] is False
    again = [f.range_mm for f in iter_frames(out_dir)]
    np.testing.assert_allclose(np.stack(again), corrected, rtol=1e-6, equal_nan=True)


def test_evaluate_reports_the_kind_and_the_sigma_coverage(
        paths: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    out = paths["dir"] / "eval"
    code, summary = _run(capsys, "evaluate", paths["frames"], "-o", out,
                         "--weights", paths["weights"])
    assert code == 0 and summary["model_kind"] == "fcn" and summary["n_frames"] == 2
    assert set(summary["summary_5mm"]) == {"raw", "calibrated", "fcn"}
    assert summary["edges_max_f1"] == {}
    observed = summary["sigma_coverage"]["observed"]
    assert all(0.0 <= x <= 1.0 for x in observed) and observed == sorted(observed)
    assert json.loads((out / "results.json").read_text())["model_kind"] == "fcn"
