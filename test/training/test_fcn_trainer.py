"""The fcn trainer: learns a non-local distortion, σ calibrated, resumable, data-parallel,
writes weights (library and CLI)."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from synthetic_fcn_frames import fcn_frames
from two_ranks import run_two_ranks, set_rank_environment, torchrun_cli

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.calibration.intrinsic import save_calibration
from tof_mpd_ros.cli.main import main
from tof_mpd_ros.correction.fcn import FCNArchitecture, FCNCorrectionModel
from tof_mpd_ros.correction.pipeline import correct
from tof_mpd_ros.correction.weights import load_weights
from tof_mpd_ros.errors import InputError, WeightsError
from tof_mpd_ros.recordings.npz import save_npz
from tof_mpd_ros.training import FCNTrainConfig, TrainConfig, evaluate_fcn, fcn_trainer, train_fcn
from tof_mpd_ros.training.fcn_trainer import (
    draw_crops,
    error_stats,
    learning_rate,
    sigma_gain,
)

H, W = 48, 64
#: 16 frames x 4 crops of 32 x 32 per epoch, batch 8: ~0.2 s an epoch on one thread
LEARN = FCNTrainConfig(epochs=40, crop_px=32, lr=3e-3, val_fraction=0.2, num_threads=1)
SMALL = FCNTrainConfig(epochs=4, crop_px=32, lr=3e-3, val_fraction=0.25, num_threads=1)


@pytest.fixture(scope="module")
def identity() -> IntrinsicCalibration:
    return IntrinsicCalibration.identity(H, W)


@pytest.fixture(scope="module")
def learned(identity: IntrinsicCalibration, tmp_path_factory: pytest.TempPathFactory):
    """One training on the box-multipath frames (~8 s), shared by the tests that read it."""
    path = tmp_path_factory.mktemp("fcn") / "w.npz"
    model, history = train_fcn(fcn_frames(16, seed=0), identity, LEARN, seed=0,
                               weights_path=path, progress=False)
    return model, history, path


def _state(model: FCNCorrectionModel) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in model.net.state_dict().items()}


def test_training_removes_most_of_a_non_local_distortion(learned) -> None:
    model, history, _ = learned
    stats = evaluate_fcn(model, fcn_frames(6, seed=99))       # frames never seen
    print("held-out:", {k: round(v, 3) for k, v in stats.items()})
    assert stats["rmse_before_mm"] > 4.0       # the box's multipath dominates the raw error
    assert stats["rmse_after_mm"] < 0.6 * stats["rmse_before_mm"]
    assert stats["within_5mm_after"] > stats["within_5mm_before"] + 0.1
    assert history[-1]["loss_nll"] < history[0]["loss_nll"] - 0.5
    assert history[-1]["val_rmse_mm"] < 0.7 * history[-1]["val_rmse_before_mm"]
    assert len(history) == LEARN.epochs and history[-1]["crops"] == 13 * 4
    assert model.metadata["train_config"]["crop_px"] == 32
    assert model.metadata["train_frames"] == 13 and len(model.metadata["val_frames"]) == 3


def test_sigma_is_calibrated_on_noise_of_known_std(identity) -> None:
    """Noise of 2 mm on a range-dependent bias and nothing else: the kernel averages the noise
    down and σ, learnt by the likelihood alone (no validation frames, no recalibration), is
    the error that is left."""
    cfg = replace(SMALL, epochs=25, val_fraction=0.0)
    model, _ = train_fcn(fcn_frames(16, seed=0, noise_mm=2.0, box_mm=0.0), identity, cfg,
                         seed=0, progress=False)
    stats = evaluate_fcn(model, fcn_frames(6, seed=99, noise_mm=2.0, box_mm=0.0))
    print("noise 2 mm:", {k: round(v, 3) for k, v in stats.items()})
    assert model.metadata["sigma_gain"] == 1.0
    # the bias is gone and the noise averaged: 2 mm over ~25 pixels would be 0.4 mm
    assert 0.3 < stats["rmse_after_mm"] < 0.7 * 2.0
    assert 1 / 1.5 < stats["median_sigma_mm"] / stats["rmse_after_mm"] < 1.5
    assert 0.85 < stats["coverage_2sigma"] < 0.99
    assert stats["coverage_1sigma"] < stats["coverage_2sigma"] < stats["coverage_3sigma"]


def test_resume_equals_uninterrupted_run(identity, tmp_path: Path, monkeypatch) -> None:
    frames = fcn_frames(6, seed=1)
    full, h_full = train_fcn(frames, identity, SMALL, seed=3, progress=False)
    # the same run killed after its second epoch's checkpoint (the cosine schedule is the
    # run's own: it resumes at the same step of it)
    validate, calls = fcn_trainer._validate, []

    def killed_at_epoch_3(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return validate(*args, **kwargs)

    monkeypatch.setattr(fcn_trainer, "_validate", killed_at_epoch_3)
    with pytest.raises(KeyboardInterrupt):
        train_fcn(frames, identity, SMALL, seed=3, checkpoint_dir=tmp_path, progress=False)
    monkeypatch.setattr(fcn_trainer, "_validate", validate)
    resumed, h_res = train_fcn(frames, identity, SMALL, seed=3, checkpoint_dir=tmp_path,
                               progress=False)
    for key, value in _state(full).items():
        assert torch.equal(value, _state(resumed)[key]), key
    assert [h["loss_nll"] for h in h_res] == [h["loss_nll"] for h in h_full]
    # another run's checkpoint is refused: another seed, or a cosine run made longer (its
    # schedule was fitted to its length); a constant-rate run may be extended
    with pytest.raises(WeightsError, match="another run"):
        train_fcn(frames, identity, SMALL, seed=4, checkpoint_dir=tmp_path, progress=False)
    with pytest.raises(WeightsError, match="another run"):
        train_fcn(frames, identity, replace(SMALL, epochs=6), seed=3, checkpoint_dir=tmp_path,
                  progress=False)
    constant = replace(SMALL, schedule="constant", epochs=2)
    train_fcn(frames, identity, constant, seed=3, checkpoint_dir=tmp_path / "c", progress=False)
    _, longer = train_fcn(frames, identity, replace(constant, epochs=3), seed=3,
                          checkpoint_dir=tmp_path / "c", progress=False)
    assert len(longer) == 3


def test_learning_rate_decays_along_a_half_cosine() -> None:
    lrs = [learning_rate(SMALL, step, 100) for step in (0, 50, 100)]
    assert lrs == pytest.approx([SMALL.lr, SMALL.lr / 2, 0.0])
    assert learning_rate(replace(SMALL, schedule="constant"), 99, 100) == SMALL.lr


def test_sigma_gain_puts_the_gaussian_share_within_two_sigma() -> None:
    rng = np.random.default_rng(0)
    sigma = rng.uniform(1.0, 4.0, 200_000)
    error = rng.normal(0.0, 1.0, sigma.size) * sigma * 1.7    # σ 1.7x too small
    assert sigma_gain(error, sigma) == pytest.approx(1.7, rel=0.02)
    with pytest.raises(InputError):
        sigma_gain(np.zeros(0), np.zeros(0))


def test_recalibration_folds_the_gain_into_the_sigma_scales(identity) -> None:
    cfg = replace(SMALL, val_fraction=0.25)
    model, _ = train_fcn(fcn_frames(8, seed=2), identity, cfg, seed=0, progress=False)
    gain = model.metadata["sigma_gain"]
    arch = model.architecture
    assert gain > 0 and arch.sigma_floor_mm == pytest.approx(FCNArchitecture().sigma_floor_mm
                                                             * gain)
    # on its validation frames 95.45 % of the pixels now lie within 2 sigma
    val = [fcn_frames(8, seed=2)[i] for i in model.metadata["val_frames"]]
    assert evaluate_fcn(model, val)["coverage_2sigma"] == pytest.approx(0.9545, abs=0.002)


def test_crops_are_seeded_by_seed_and_epoch() -> None:
    a = draw_crops([0, 2, 5], (H, W), SMALL, seed=1, epoch=3)
    assert torch.equal(a, draw_crops([0, 2, 5], (H, W), SMALL, seed=1, epoch=3))
    assert not torch.equal(a, draw_crops([0, 2, 5], (H, W), SMALL, seed=1, epoch=4))
    assert sorted(a[:, 0].tolist()) == [0] * 4 + [2] * 4 + [5] * 4
    assert a[:, 1].max() <= H - 32 and a[:, 2].max() <= W - 32 and a.min() >= 0
    whole = draw_crops([0], (H, W), replace(SMALL, crop_px=200), seed=1, epoch=0)
    assert whole[:, 1:].abs().sum() == 0       # a frame smaller than the crop is used whole


def test_weights_round_trip_gives_the_same_correction(learned) -> None:
    model, _, path = learned
    loaded = load_weights(path)
    assert isinstance(loaded, FCNCorrectionModel) and loaded.kind == "fcn"
    assert loaded.max_sigma_mm == LEARN.max_sigma_mm
    assert loaded.metadata["training_data_digest"] == model.metadata["training_data_digest"]
    assert loaded.metadata["final"]["val_rmse_mm"] == pytest.approx(
        model.metadata["final"]["val_rmse_mm"])
    f = fcn_frames(2, seed=5)
    r, a = np.stack([x.range_mm for x in f]), np.stack([x.amplitude for x in f])
    mine, theirs = correct(model, r, a), correct(loaded, r, a)
    for name in ("range_mm", "range_f_mm", "sigma_mm", "confidence"):
        np.testing.assert_array_equal(getattr(mine, name), getattr(theirs, name), err_msg=name)


def test_bad_config_and_inputs_are_refused(identity, tmp_path: Path) -> None:
    for bad in ({"epochs": 0}, {"batch_size": 0}, {"crop_px": 0}, {"crops_per_frame": 0},
                {"lr": 0.0}, {"weight_decay": -1.0}, {"val_fraction": 1.0},
                {"target_clip_mm": 0.0}, {"max_sigma_mm": -1.0}, {"num_threads": 0},
                {"architecture": "unet"}, {"epochs": 2.5}):
        with pytest.raises(InputError):
            FCNTrainConfig(**bad)
    frames = fcn_frames(2, seed=0)
    with pytest.raises(InputError, match="FCNTrainConfig"):
        train_fcn(frames, identity, TrainConfig(), progress=False)
    with pytest.raises(InputError):
        train_fcn(frames, IntrinsicCalibration.identity(H, W + 1), SMALL, progress=False)
    with pytest.raises(InputError, match="reference"):
        train_fcn([replace(frames[0], reference_mm=None)], identity, SMALL, progress=False)


def test_existing_weights_are_refused_before_training(identity, tmp_path: Path) -> None:
    path = tmp_path / "w.npz"
    path.write_bytes(b"not to be replaced")
    with pytest.raises(WeightsError, match="exists"):
        train_fcn(fcn_frames(2, seed=0), identity, SMALL, weights_path=path,
                  checkpoint_dir=tmp_path / "ckpt", progress=False)
    assert not (tmp_path / "ckpt").exists()    # refused before anything was trained
    assert path.read_bytes() == b"not to be replaced"


def test_error_stats_on_known_errors() -> None:
    before = np.array([10.0, -10.0, 4.0, 1.0, 30.0])
    after = np.array([0.5, -1.5, 2.5, 0.0, 20.0])
    sigma = np.array([1.0, 1.0, 1.0, 1.0, 12.0])
    s = error_stats(before, after, sigma, max_sigma_mm=10.0)
    assert s["pixels"] == 5
    assert s["rmse_after_mm"] == pytest.approx(math.sqrt((0.25 + 2.25 + 6.25 + 400) / 5))
    assert s["mae_before_mm"] == pytest.approx(11.0)
    assert s["within_2mm_after"] == pytest.approx(3 / 5)
    assert s["within_5mm_before"] == pytest.approx(2 / 5)
    assert (s["coverage_1sigma"], s["coverage_2sigma"], s["coverage_3sigma"]) == \
        pytest.approx((2 / 5, 4 / 5, 1.0))
    assert s["flagged_fraction"] == pytest.approx(1 / 5)
    assert s["flag_precision"] == 1.0 and s["flag_recall"] == 1.0
    assert s["kept_rmse_mm"] == pytest.approx(math.sqrt((0.25 + 2.25 + 6.25) / 4))


def test_cli_trains_the_fcn_kind(identity, tmp_path: Path,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    frames = [replace(f, stamp_ns=1_000_000 * i) for i, f in enumerate(fcn_frames(4, seed=2))]
    save_npz(tmp_path / "frames.npz", frames)
    save_calibration(tmp_path / "cal.npz", identity)
    out = tmp_path / "w.npz"
    argv = ["train", str(tmp_path / "frames.npz"), "--calibration", str(tmp_path / "cal.npz"),
            "--model", "fcn", "--epochs", "2", "--crop-px", "32", "--batch-size", "4",
            "--lr", "0.002", "--target-clip-mm", "50", "-o", str(out)]
    assert main(argv) == 0, capsys.readouterr().err
    model = load_weights(out)
    assert isinstance(model, FCNCorrectionModel)
    config = model.metadata["train_config"]
    assert (config["crop_px"], config["batch_size"], config["lr"], config["target_clip_mm"],
            config["epochs"]) == (32, 4, 0.002, 50.0, 2)
    summary = json.loads(out.with_suffix(".json").read_text())
    assert summary["model"] == "fcn" and summary["epochs"] == 2 and summary["frames"] == 4
    assert len(summary["history"]) == 2 and "val_rmse_mm" in summary["final"]
    printed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert printed["weights"] == str(out) and "history" not in printed
    assert {p.name for p in tmp_path.iterdir()} == {"frames.npz", "cal.npz", "w.npz", "w.json"}
    # the fcn kind takes one truncation, not the patch trainer's candidates
    assert main([*argv[:-2], "--target-clip-mm", "15,auto", "-o", str(tmp_path / "x.npz"),
                 ]) == 2
    assert "one --target-clip-mm" in capsys.readouterr().err


#: noise of 2 mm on a range bias (learnt steadily in a few steps), 6 train frames x 8 crops
DIST = FCNTrainConfig(epochs=6, crop_px=32, batch_size=8, crops_per_frame=8, lr=3e-3,
                      val_fraction=0.25, architecture=FCNArchitecture(widths=(8, 16, 16)),
                      num_threads=1)


def _dist_frames() -> list:
    return fcn_frames(8, seed=0, noise_mm=2.0, box_mm=0.0)


def _rank_main(rank: int, world: int, port: int, out: str) -> None:
    """One rank: what torchrun would set up, then the library's own train_fcn()."""
    set_rank_environment(rank, world, port)
    model, history = train_fcn(_dist_frames(), IntrinsicCalibration.identity(H, W), DIST,
                               seed=3, checkpoint_dir=Path(out) / "ckpt",
                               weights_path=Path(out) / "w.npz", progress=False)
    torch.save({"state": model.net.state_dict(), "history": history},
               Path(out) / f"rank{rank}.pt")


def test_two_processes_train_in_step(tmp_path: Path) -> None:
    ranks = run_two_ranks(_rank_main, tmp_path)
    history = ranks[0]["history"]
    for a, b in zip(history, ranks[1]["history"], strict=True):
        for key in ("loss_nll", "crops", "pixels", "val_rmse_mm", "val_nll"):
            assert a[key] == b[key], key
    assert history[-1]["loss_nll"] < history[0]["loss_nll"] - 0.1
    assert history[-1]["val_nll"] < history[0]["val_nll"]
    assert history[0]["crops"] == 6 * DIST.crops_per_frame   # the ranks together: one epoch
    weights = load_weights(tmp_path / "w.npz")
    for key, value in weights.net.state_dict().items():
        assert torch.equal(value, ranks[0]["state"][key]), key
    ckpt = torch.load(tmp_path / "ckpt" / "checkpoint.pt", weights_only=True)
    assert ckpt["epoch"] == DIST.epochs and '"world": 2' in ckpt["fingerprint"]
    # the same steps as one process on the same crops, up to the order of summation
    one, h_one = train_fcn(_dist_frames(), IntrinsicCalibration.identity(H, W), DIST,
                           seed=3, progress=False)
    gap = max(float((v - ranks[0]["state"][k]).abs().max())
              for k, v in one.net.state_dict().items())
    print(f"largest parameter difference, 2 ranks vs 1 process: {gap:.2e}")
    # Adam amplifies those rounding differences over the 36 steps: changes of one ulp in the
    # kernel mean, or in a box filter's sums, moved this gap between 4e-7 and 8e-5 (session
    # 17); missing steps differ by the steps themselves (one epoch fewer, 6 steps: 2.6e-2)
    for key, value in one.net.state_dict().items():
        torch.testing.assert_close(value, ranks[0]["state"][key], atol=2e-4, rtol=1e-4,
                                   msg=key)
    assert h_one[-1]["loss_nll"] == pytest.approx(history[-1]["loss_nll"], rel=1e-3)


def test_torchrun_launch_of_the_cli_trains_the_fcn_kind(identity, tmp_path: Path) -> None:
    """``torchrun --nproc_per_node 2 -m tof_mpd_ros.cli.main train --model fcn ...``: two
    processes, rank 0 writes the weights, the summary and the checkpoint; the loss falls."""
    frames = [replace(f, stamp_ns=1_000_000 * i) for i, f in enumerate(_dist_frames())]
    save_npz(tmp_path / "frames.npz", frames)
    save_calibration(tmp_path / "cal.npz", identity)
    done = torchrun_cli(["train", str(tmp_path / "frames.npz"),
                         "-o", str(tmp_path / "w.npz"), "--calibration", str(tmp_path / "cal.npz"),
                         "--model", "fcn", "--epochs", "4", "--crop-px", "32", "--batch-size",
                         "8", "--lr", "0.003", "--checkpoint-dir", str(tmp_path / "ckpt")])
    assert done.returncode == 0, done.stderr[-3000:]
    summary = json.loads((tmp_path / "w.json").read_text())
    assert summary["model"] == "fcn" and summary["world"] == 2 and summary["epochs"] == 4
    assert summary["history"][-1]["loss_nll"] < summary["history"][0]["loss_nll"]
    assert isinstance(load_weights(tmp_path / "w.npz"), FCNCorrectionModel)
    assert (tmp_path / "ckpt" / "checkpoint.pt").is_file()


def test_cli_holds_out_frames_or_whole_sessions_for_validation(identity, tmp_path: Path) -> None:
    """Three recording sessions (an hour apart) of two frames each: the validation frames, on
    which σ's gain is fitted, are single frames by default, one whole session on request."""
    stamps = [0, 10**8, 3600 * 10**9, 3600 * 10**9 + 10**8, 7200 * 10**9, 7200 * 10**9 + 10**8]
    frames = [replace(f, stamp_ns=s) for f, s in zip(fcn_frames(6, seed=2), stamps, strict=True)]
    save_npz(tmp_path / "frames.npz", frames)
    save_calibration(tmp_path / "cal.npz", identity)
    base = ["train", str(tmp_path / "frames.npz"), "--calibration", str(tmp_path / "cal.npz"),
            "--model", "fcn", "--epochs", "1", "--crop-px", "32", "--batch-size", "4"]
    assert main([*base, "--val-split", "session", "-o", str(tmp_path / "s.npz")]) == 0
    assert load_weights(tmp_path / "s.npz").metadata["val_frames"] in ([0, 1], [2, 3], [4, 5])
    assert main([*base, "-o", str(tmp_path / "f.npz")]) == 0
    assert len(load_weights(tmp_path / "f.npz").metadata["val_frames"]) == 1
