"""``tof-mpd calibrate install``: a new intrinsic calibration in a weights file, the networks
kept; the installed full frame's central window is the crop model it came from; evaluate runs
full-frame weights on smaller frames through that window."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from tof_mpd_ros.calibration import IntrinsicCalibration, save_calibration
from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.cli.main import main
from tof_mpd_ros.correction.fcn import FCNCorrectionModel
from tof_mpd_ros.correction.pipeline import (
    CorrectionModel,
    central_window,
    correct,
    processed_window,
)
from tof_mpd_ros.correction.weights import load_weights, save_weights
from tof_mpd_ros.errors import InputError
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.recordings.npz import save_npz


def _calibration(height: int, width: int, seed: int) -> IntrinsicCalibration:
    rng = np.random.default_rng(seed)
    return IntrinsicCalibration(rng.normal(0, 3, (height, width)),
                                rng.uniform(0.98, 1.02, (height, width)),
                                rng.normal(0, 1, (height, width)),
                                np.ones((height, width), bool))


@pytest.mark.parametrize("kind", ["patch", "fcn"])
def test_install_keeps_the_networks_and_takes_the_calibrations_frame(
        kind: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    crop = _calibration(14, 18, seed=0)
    build = CorrectionModel if kind == "patch" else FCNCorrectionModel
    save_weights(tmp_path / "crop.npz", build.untrained(crop, seed=1))
    full = _calibration(24, 32, seed=2)
    save_calibration(tmp_path / "full.npz", full)
    assert main(["calibrate", "install", str(tmp_path / "full.npz"), "--weights",
                 str(tmp_path / "crop.npz"), "-o", str(tmp_path / "out.npz")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frame_before"] == [18, 14] and summary["frame"] == [32, 24]
    before, after = load_weights(tmp_path / "crop.npz"), load_weights(tmp_path / "out.npz")
    assert after.kind == kind and after.shape == (24, 32)
    np.testing.assert_array_equal(after.calibration.c0, full.c0)
    nets = (lambda m: m.range_net) if kind == "patch" else (lambda m: m.net)
    for a, b in zip(nets(before).state_dict().values(), nets(after).state_dict().values(),
                    strict=True):
        assert torch.equal(a, b)
    assert after.metadata["calibration_installed"]["frame_before"] == [18, 14]
    # the central 18 x 14 window of the installed model: the crop of the new calibration
    window = central_window(after, 18, 14)
    np.testing.assert_array_equal(window.calibration.c1, full.c1[5:19, 7:25])
    rng = np.random.default_rng(3)
    r = rng.uniform(300, 400, (24, 32)).astype(np.float32)
    a = rng.uniform(100, 900, (24, 32)).astype(np.float32)
    np.testing.assert_array_equal(correct(window, r[5:19, 7:25], a[5:19, 7:25]).calibrated_mm,
                                  correct(after, r, a).calibrated_mm[5:19, 7:25])


def test_a_window_larger_than_the_model_is_refused() -> None:
    model = FCNCorrectionModel.untrained(_calibration(14, 18, seed=0))
    with pytest.raises(InputError, match="does not fit"):
        central_window(model, 20, 14)
    assert central_window(model, 18, 14) is model


@pytest.mark.parametrize("kind", ["patch", "fcn"])
def test_evaluate_with_full_frame_weights_scores_smaller_frames_on_their_central_window(
        kind: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Full-sensor weights (the shipped ones) on recordings of the paper's crop: evaluate runs
    the central window of the weights, as the node and `correct` do."""
    full = _calibration(24, 32, seed=4)
    build = CorrectionModel if kind == "patch" else FCNCorrectionModel
    save_weights(tmp_path / "full.npz", build.untrained(full, seed=1))
    rng = np.random.default_rng(5)
    frames = []
    for i in range(2):
        ref = rng.uniform(300, 400, (14, 18)).astype(np.float32)
        frames.append(ToFFrame(ref + rng.normal(0, 2, ref.shape).astype(np.float32),
                               rng.uniform(100, 900, ref.shape).astype(np.float32),
                               Intrinsics.from_fov(18, 14, 60.0), reference_mm=ref,
                               stamp_ns=i))
    save_npz(tmp_path / "small.npz", frames)
    assert main(["evaluate", str(tmp_path / "small.npz"), "--weights", str(tmp_path / "full.npz"),
                 "-o", str(tmp_path / "eval")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["n_frames"] == 2 and summary["model_kind"] == kind
    # frames larger than the weights' frame still do not fit
    big = [ToFFrame(np.full((30, 40), 350.0, np.float32), np.full((30, 40), 500.0, np.float32),
                    Intrinsics.from_fov(40, 30, 60.0), reference_mm=np.full((30, 40), 350.0,
                                                                            np.float32))]
    save_npz(tmp_path / "big.npz", big)
    assert main(["evaluate", str(tmp_path / "big.npz"), "--weights", str(tmp_path / "full.npz"),
                 "-o", str(tmp_path / "eval_big")]) == 2
    assert "40x30" in capsys.readouterr().err


def test_processed_window_is_the_crop_or_the_model_clipped_to_the_frame() -> None:
    assert processed_window((240, 320), (512, 512)) == (240, 320)            # cropped to it
    assert processed_window((240, 320), (140, 180)) == (140, 180)            # corrected whole
    assert processed_window((240, 320), (512, 512), (180, 140)) == (140, 180)
    assert processed_window((240, 320), (100, 512), (180, 140)) == (100, 180)
