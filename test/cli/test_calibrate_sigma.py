"""``tof-mpd calibrate sigma``: an fcn weights file's σ refitted on reference frames of the
camera it will run on. The gain puts 95.45 % of those pixels within 2 σ, carries to other
frames of the same camera, scales σ and nothing else, composes, and is refused where it
cannot apply."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.cli.main import main
from tof_mpd_ros.correction.fcn import FCNCorrectionModel
from tof_mpd_ros.correction.pipeline import CorrectionModel, correct
from tof_mpd_ros.correction.weights import load_weights, save_weights
from tof_mpd_ros.evaluation.uncertainty import coverage
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.recordings import save_npz

H, W = 24, 32


def _frames(seed: int, n: int = 3, *, offset_mm: float = 6.0, noise_mm: float = 2.0,
            reference: bool = True) -> list[ToFFrame]:
    """A tilted plane with a box, seen with a constant offset and Gaussian noise: an untrained
    network leaves errors of about ``offset_mm`` ± ``noise_mm`` for σ to describe."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        truth = 480.0 + np.zeros((H, W)) + 0.4 * np.arange(W)
        truth[6:14, 8:22] -= 50.0
        measured = truth + offset_mm + rng.normal(0, noise_mm, truth.shape)
        out.append(ToFFrame(measured.astype(np.float32), np.full((H, W), 0.6, np.float32),
                            Intrinsics.from_fov(W, H, 60.0),
                            reference_mm=truth.astype(np.float32) if reference else None,
                            stamp_ns=100 * seed + i + 1))
    return out


def _two_sigma_share(model: FCNCorrectionModel, frames: list[ToFFrame]) -> float:
    errors, sigmas = [], []
    for f in frames:
        res = correct(model, f.range_mm, f.amplitude)
        ok = res.valid & np.isfinite(f.reference_mm)
        errors.append((res.range_f_mm - f.reference_mm)[ok])
        sigmas.append(res.sigma_mm[ok])
    return coverage(np.concatenate(errors), np.concatenate(sigmas))["2"]


@pytest.fixture()
def files(tmp_path: Path) -> dict[str, Path]:
    torch.manual_seed(0)
    model = FCNCorrectionModel.untrained(IntrinsicCalibration.identity(H, W), seed=4)
    save_npz(tmp_path / "site.npz", _frames(1))
    save_npz(tmp_path / "other.npz", _frames(2))
    return {"dir": tmp_path, "weights": save_weights(tmp_path / "fcn.npz", model),
            "site": tmp_path / "site.npz", "other": tmp_path / "other.npz"}


def _run(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, dict]:
    code = main([str(a) for a in argv])
    lines = [x for x in capsys.readouterr().out.splitlines() if x.startswith("{")]
    return code, json.loads(lines[-1]) if lines else {}


def test_the_gain_covers_the_site_frames_and_carries_to_others(
        files: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    before = load_weights(files["weights"])
    assert _two_sigma_share(before, _frames(2)) < 0.5  # an untrained σ says little

    code, summary = _run(capsys, "calibrate", "sigma", files["site"], "--weights",
                         files["weights"], "-o", files["dir"] / "site_fcn.npz")
    assert code == 0 and summary["frames"] == 3 and summary["frames_without_reference"] == 0
    assert summary["pixels"] == 3 * H * W
    assert summary["coverage_after"]["2"] == pytest.approx(0.9545, abs=0.005)
    assert summary["coverage_before"]["2"] < 0.5 and summary["gain"] > 1.0

    after = load_weights(files["dir"] / "site_fcn.npz")
    # other frames of the same camera: near the Gaussian's 95.45 % too
    assert _two_sigma_share(after, _frames(2)) == pytest.approx(0.9545, abs=0.02)
    # σ scaled by the gain at every pixel, the correction and the calibration untouched
    frame = _frames(2)[0]
    old, new = (correct(m, frame.range_mm, frame.amplitude) for m in (before, after))
    np.testing.assert_allclose(new.sigma_mm, summary["gain"] * old.sigma_mm, rtol=1e-5)
    np.testing.assert_array_equal(new.range_f_mm, old.range_f_mm)
    np.testing.assert_array_equal(new.range_mm, old.range_mm)  # the gate moved with σ
    assert after.max_sigma_mm == pytest.approx(summary["gain"] * before.max_sigma_mm)
    np.testing.assert_array_equal(after.calibration.c0, before.calibration.c0)
    entry, = after.metadata["sigma_recalibrations"]
    assert entry["gain"] == pytest.approx(summary["gain"]) and entry["frames"] == 3
    assert str(files["site"]) in entry["source"]


def test_a_second_fit_on_the_same_frames_changes_nothing_and_is_recorded(
        files: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    once, twice = files["dir"] / "once.npz", files["dir"] / "twice.npz"
    _run(capsys, "calibrate", "sigma", files["site"], "--weights", files["weights"], "-o", once)
    code, summary = _run(capsys, "calibrate", "sigma", files["site"], "--weights", once,
                         "-o", twice)
    assert code == 0 and summary["gain"] == pytest.approx(1.0, abs=1e-3)
    assert len(load_weights(twice).metadata["sigma_recalibrations"]) == 2


def test_frames_without_reference_are_counted_and_weights_without_sigma_refused(
        files: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    save_npz(files["dir"] / "mixed.npz", [*_frames(3, 2), *_frames(4, 1, reference=False)])
    code, summary = _run(capsys, "calibrate", "sigma", files["dir"] / "mixed.npz", "--weights",
                         files["weights"], "-o", files["dir"] / "m.npz")
    assert code == 0 and summary["frames"] == 2 and summary["frames_without_reference"] == 1

    save_npz(files["dir"] / "bare.npz", _frames(5, 2, reference=False))
    assert main(["calibrate", "sigma", str(files["dir"] / "bare.npz"), "--weights",
                 str(files["weights"]), "-o", str(files["dir"] / "b.npz")]) == 2
    assert "no frame with a reference" in capsys.readouterr().err

    patch = save_weights(files["dir"] / "patch.npz",
                         CorrectionModel.untrained(IntrinsicCalibration.identity(H, W), seed=1))
    assert main(["calibrate", "sigma", str(files["site"]), "--weights", str(patch),
                 "-o", str(files["dir"] / "p.npz")]) == 2
    assert "predicts no sigma" in capsys.readouterr().err
    assert not (files["dir"] / "p.npz").exists() and not (files["dir"] / "b.npz").exists()


def test_full_sensor_weights_keep_their_frame_and_take_the_windows_gain(
        files: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    full = FCNCorrectionModel.untrained(IntrinsicCalibration.identity(2 * H, 2 * W), seed=4)
    weights = save_weights(files["dir"] / "full.npz", full)
    code, summary = _run(capsys, "calibrate", "sigma", files["site"], "--weights", weights,
                         "-o", files["dir"] / "full_site.npz")
    assert code == 0
    after = load_weights(files["dir"] / "full_site.npz")
    assert after.shape == (2 * H, 2 * W) and "central_window" not in after.metadata
    a, b = after.architecture, full.architecture
    assert a.sigma_scale_mm == pytest.approx(summary["gain"] * b.sigma_scale_mm)
    assert a.sigma_floor_mm == pytest.approx(summary["gain"] * b.sigma_floor_mm)
