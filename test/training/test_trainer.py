"""Trainer: learns a patch-dependent distortion, deterministic, resumable, writes weights."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from synthetic_training_frames import synthetic_frames

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.correction.pipeline import correct
from tof_mpd_ros.correction.weights import load_weights
from tof_mpd_ros.errors import InputError, WeightsError
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.training import TrainConfig, train
from tof_mpd_ros.training.trainer import split_frames

H, W = 40, 48
FAST = TrainConfig(epochs=3, val_fraction=0.25, val_samples_per_frame=500,
                   max_samples_per_frame=600)


@pytest.fixture(scope="module")
def frames() -> list[ToFFrame]:
    return synthetic_frames(8, seed=0)


@pytest.fixture(scope="module")
def identity() -> IntrinsicCalibration:
    return IntrinsicCalibration.identity(H, W)


def _params(model) -> list[torch.Tensor]:
    return [p.detach().clone() for p in (*model.range_net.parameters(),
                                         *model.boundary_nets.parameters())]


def _rmse(model, test_frames, use_f: bool) -> float:
    errs = []
    for f in test_frames:
        res = correct(model, f.range_mm, f.amplitude, use_range_net=use_f, use_boundary=False)
        ok = np.isfinite(f.reference_mm)
        errs.append(res.range_f_mm[ok] - f.reference_mm[ok])
    return float(np.sqrt(np.mean(np.concatenate(errs) ** 2)))


def test_training_removes_most_of_a_learnable_distortion(frames, identity) -> None:
    model, history = train(frames, identity, TrainConfig(epochs=8, val_fraction=0.25),
                           seed=0, progress=False)
    held_out = synthetic_frames(4, seed=123)
    before, after = _rmse(model, held_out, False), _rmse(model, held_out, True)
    assert before > 2.0                  # the over-shoot bump dominates the raw error
    assert after < 0.45 * before         # F removes most of it on unseen frames
    assert history[-1]["loss_range"] < 0.3 * history[0]["loss_range"]
    assert history[-1]["val_rmse_mm"] < 0.5 * history[-1]["val_rmse_before_mm"]
    assert history[-1]["val_edge_recall"] > 0.8   # G heads fire on the box outline
    assert history[-1]["patches_per_s"] > 0


def test_same_seed_same_model_other_seed_differs(frames, identity) -> None:
    a, ha = train(frames, identity, FAST, seed=5, progress=False)
    b, hb = train(frames, identity, FAST, seed=5, progress=False)
    c, _ = train(frames, identity, FAST, seed=6, progress=False)
    assert all(torch.equal(p, q) for p, q in zip(_params(a), _params(b), strict=True))
    assert [h["loss_range"] for h in ha] == [h["loss_range"] for h in hb]
    assert not torch.equal(_params(a)[0], _params(c)[0])


def test_resume_equals_uninterrupted_run(frames, identity, tmp_path: Path) -> None:
    full, h_full = train(frames, identity, FAST, seed=3, progress=False)
    first, _ = train(frames, identity, TrainConfig(**{**FAST.__dict__, "epochs": 1}), seed=3,
                     checkpoint_dir=tmp_path, progress=False)
    assert (tmp_path / "checkpoint.pt").is_file()
    resumed, h_res = train(frames, identity, FAST, seed=3, checkpoint_dir=tmp_path,
                           progress=False)
    assert all(torch.equal(p, q) for p, q in zip(_params(full), _params(resumed), strict=True))
    assert [h["loss_range"] for h in h_res] == [h["loss_range"] for h in h_full]
    assert not torch.equal(_params(first)[0], _params(full)[0])
    state = torch.load(tmp_path / "checkpoint.pt", weights_only=True)   # no pickle needed
    assert state["epoch"] == 3


def test_checkpoint_of_another_run_or_corrupt_is_refused(frames, identity, tmp_path) -> None:
    train(frames, identity, FAST, seed=1, checkpoint_dir=tmp_path, progress=False)
    with pytest.raises(WeightsError, match="belongs to another run"):
        train(frames, identity, FAST, seed=2, checkpoint_dir=tmp_path, progress=False)
    (tmp_path / "checkpoint.pt").write_bytes(b"garbage")
    with pytest.raises(WeightsError, match="unreadable"):
        train(frames, identity, FAST, seed=1, checkpoint_dir=tmp_path, progress=False)


def test_weights_file_written_and_loadable(frames, identity, tmp_path: Path) -> None:
    path = tmp_path / "model.npz"
    model, _ = train(frames, identity, FAST, seed=0, weights_path=path, progress=False)
    back = load_weights(path, expected_shape=(H, W))
    assert back.metadata["file"]["training_data_digest"] == model.metadata[
        "training_data_digest"]
    assert back.encoding == model.encoding
    with pytest.raises(WeightsError, match="exists; pass overwrite=True"):
        train(frames, identity, FAST, seed=0, weights_path=path, progress=False)
    f = frames[0]
    np.testing.assert_array_equal(
        correct(back, f.range_mm, f.amplitude, use_boundary=False).range_f_mm,
        correct(model, f.range_mm, f.amplitude, use_boundary=False).range_f_mm)


def test_split_is_by_frame_and_seeded() -> None:
    tr, va = split_frames(10, 0.2, seed=0)
    assert len(va) == 2 and sorted(tr + va) == list(range(10))
    assert split_frames(10, 0.2, seed=0) == (tr, va)
    assert split_frames(1, 0.5, seed=0) == ([0], [])
    scenes = [0, 0, 0, 1, 1, 1, 2, 2, 2, 3]
    tr, va = split_frames(10, 0.25, seed=1, groups=scenes)
    assert va and sorted(tr + va) == list(range(10))
    assert {scenes[i] for i in tr}.isdisjoint({scenes[i] for i in va})   # whole scenes


def test_truncation_candidates_are_chosen_on_validation(frames, identity, tmp_path) -> None:
    """One F per candidate T learns from the same patches; the one most often within 5 mm on
    the validation pixels is kept (and saved); 'None' resolves to the data's own T."""
    cfg = TrainConfig(**{**FAST.__dict__, "target_clip_mm": (15.0, 40.0, None),
                         "tune_edge_thresholds": False})
    model, history = train(frames, identity, cfg, seed=2, progress=False,
                           weights_path=tmp_path / "w.npz")
    scores = history[-1]["val_within_5mm_per_clip"]
    assert {"15.0", "40.0"} <= set(scores) and all(0.0 <= v <= 1.0 for v in scores.values())
    chosen = model.range_net.target_clip_mm
    assert scores[str(chosen)] == max(scores.values())
    assert model.metadata["target_clip_mm"] == chosen
    assert load_weights(tmp_path / "w.npz").range_net.target_clip_mm == chosen
    with pytest.raises(InputError):
        TrainConfig(target_clip_mm=(15.0, -1.0))
    with pytest.raises(InputError):
        TrainConfig(target_clip_mm=())
