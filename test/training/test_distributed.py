"""Data-parallel training: two CPU processes (gloo) end with identical networks, the loss
falls, rank 0 alone writes the files, and a torchrun launch of the CLI trains the same way."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
import torch
from synthetic_training_frames import synthetic_frames
from two_ranks import run_two_ranks, set_rank_environment, torchrun_cli

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.calibration.intrinsic import save_calibration
from tof_mpd_ros.correction.weights import load_weights
from tof_mpd_ros.errors import InputError
from tof_mpd_ros.recordings.npz import save_npz
from tof_mpd_ros.training import TrainConfig, train
from tof_mpd_ros.training.distributed import Ranks, rank_batch_size, shard_pixels, start

H, W = 40, 48
CONFIG = TrainConfig(epochs=4, batch_size=200, val_fraction=0.25, val_samples_per_frame=400,
                     max_samples_per_frame=800, target_clip_mm=15.0,
                     tune_edge_thresholds=False)


def _rank_main(rank: int, world: int, port: int, out: str) -> None:
    """One rank: what torchrun would set up, then the library's own train()."""
    set_rank_environment(rank, world, port)
    torch.set_num_threads(1)
    frames = synthetic_frames(8, seed=0)
    model, history = train(frames, IntrinsicCalibration.identity(H, W), CONFIG, seed=3,
                           checkpoint_dir=Path(out) / "ckpt", weights_path=Path(out) / "w.npz",
                           progress=False)
    state = {f"F.{k}": v for k, v in model.range_net.state_dict().items()}
    state.update({f"G.{k}": v for k, v in model.boundary_nets.state_dict().items()})
    torch.save({"state": state, "history": history}, Path(out) / f"rank{rank}.pt")


def test_two_processes_train_in_step(tmp_path: Path) -> None:
    ranks = run_two_ranks(_rank_main, tmp_path)
    history = ranks[0]["history"]
    # every rank reports the losses over all ranks, and validates alike
    for a, b in zip(history, ranks[1]["history"], strict=True):
        for key in ("loss_range", "loss_boundary", "patches", "val_rmse_mm"):
            assert a[key] == b[key], key
    assert history[-1]["loss_range"] < 0.6 * history[0]["loss_range"]
    assert history[-1]["loss_boundary"] < history[0]["loss_boundary"]
    # the two ranks together saw one epoch's pixels: 6 train frames x 800
    assert history[0]["patches"] == 6 * 800
    # rank 0 wrote the weights and the checkpoint
    weights = load_weights(tmp_path / "w.npz")
    for key, value in weights.range_net.state_dict().items():
        assert torch.equal(value, ranks[0]["state"][f"F.{key}"]), key
    ckpt = torch.load(tmp_path / "ckpt" / "checkpoint.pt", weights_only=True)
    assert ckpt["epoch"] == CONFIG.epochs and '"world": 2' in ckpt["fingerprint"]


def test_pixels_are_dealt_out_and_batches_split() -> None:
    flat = torch.arange(11)
    two = [shard_pixels(flat, Ranks(r, 2)) for r in range(2)]
    assert [t.tolist() for t in two] == [[0, 2, 4, 6, 8], [1, 3, 5, 7, 9]]
    assert shard_pixels(flat, Ranks()) is flat
    assert rank_batch_size(500, Ranks(1, 4)) == 125
    with pytest.raises(InputError, match="multiple"):
        rank_batch_size(500, Ranks(0, 3))
    assert start(distributed=None) == Ranks()  # no torchrun: one process
    with pytest.raises(InputError, match="torchrun"):
        start(distributed=True)


def test_torchrun_launch_of_the_cli(tmp_path: Path) -> None:
    """``torchrun --nproc_per_node 2 -m tof_mpd_ros.cli.main train ...`` trains on two
    processes; rank 0 writes the weights and the summary."""
    frames = [replace(f, stamp_ns=1_000_000 * i) for i, f in enumerate(synthetic_frames(6, seed=1))]
    save_npz(tmp_path / "frames.npz", frames)
    save_calibration(tmp_path / "cal.npz", IntrinsicCalibration.identity(H, W))
    done = torchrun_cli(["train", str(tmp_path / "frames.npz"),
                         "-o", str(tmp_path / "w.npz"), "--calibration", str(tmp_path / "cal.npz"),
                         "--epochs", "2", "--batch-size", "100", "--max-samples-per-frame", "300",
                         "--target-clip-mm", "15", "--edge-thresholds", "paper"])
    assert done.returncode == 0, done.stderr[-3000:]
    summary = json.loads((tmp_path / "w.json").read_text())
    assert summary["epochs"] == 2 and summary["world"] == 2
    assert summary["history"][1]["loss_range"] < summary["history"][0]["loss_range"]
    load_weights(tmp_path / "w.npz")
