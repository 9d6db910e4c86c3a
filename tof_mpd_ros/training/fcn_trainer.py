"""Training of the ``"fcn"`` kind (:mod:`tof_mpd_ros.correction.fcn`, issue 17 item 1).

``train_fcn(frames, calibration, config, seed=...)`` calibrates every frame once, computes the
network's input planes on the *whole* frames (so the frame-median normalisation of
:func:`~tof_mpd_ros.correction.fcn.fcn_inputs` is the one inference sees) and the target
``t = clip(R* - R, -T, T)`` (R the calibrated range, R* the reference; T = ``target_clip_mm``,
100 mm by default), then trains :class:`~tof_mpd_ros.correction.fcn.ResidualFCN` with Adam on
random square crops:

* loss: :func:`~tof_mpd_ros.correction.fcn.gaussian_nll` of the target under the predicted
  (correction, σ), averaged over the crop pixels that have a valid measurement and a reference,
  each pixel weighted by its σ^(2 β) (β-NLL, ``beta``; the history reports the plain NLL).
  The clip keeps a few flying pixels 300 mm off from dominating the mean; the likelihood lets
  the network give such pixels a large σ (beyond ``max_sigma_mm`` they take a sure
  neighbour's side at inference, :func:`~tof_mpd_ros.correction.fcn.resolve_to_a_side`)
  instead of bending the correction of their neighbours towards them;
* learning rate: ``lr`` decayed to 0 along a half cosine over every step of the run
  (``schedule="cosine"``; the last epoch is the one kept), or constant. A function of the step
  alone, so a resumed run takes the same steps;
* σ recalibration: after the last epoch one gain on σ is fitted on the validation frames so
  that 95.45 % of their pixels lie within 2 σ (the Gaussian's share), and folded into the
  network's σ output scales (``metadata["sigma_gain"]``). A network trained on a few scenes
  is over-confident on scenes it has not seen; a single scale fixes that without touching the
  correction (no validation frames: gain 1). :func:`recalibrate_sigma_on_frames` (``tof-mpd
  calibrate sigma``) refits that gain later on other reference frames, e.g. the site's own;
* crops: every epoch draws ``crops_per_frame`` crops of ``crop_px`` x ``crop_px`` per training
  frame (a frame smaller than that is used whole) at uniform positions, shuffled, from a
  generator seeded by ``(seed, epoch)``: runs are deterministic and a resumed run is identical
  to an uninterrupted one;
* validation: after every epoch, on the whole validation frames (split by frame or by
  caller-given groups such as scenes, :func:`.trainer.split_frames`) through
  :func:`~tof_mpd_ros.correction.fcn.run_fcn`, i.e. as at inference: RMSE and the fraction
  within 5 mm before and after the correction, the NLL, and the σ coverage (the fraction of
  pixels with ``|error| <= k σ``, k = 1, 2, 3; 0.683 / 0.954 / 0.997 for a calibrated σ).

Checkpoints use :func:`.trainer.save_checkpoint` / :func:`.trainer.load_checkpoint` (tensors and
plain data, ``weights_only=True``) with a fingerprint of the configuration (``epochs`` and
``num_threads`` left out: a finished run can be extended), the seed, a SHA-256 of the frames and
the calibration, the validation frames and the number of processes.

Data-parallel (:mod:`.distributed`): every rank draws the same crops and takes every W-th one
from the r-th, stepping on ``batch_size / W`` crops; each rank's loss is its NLL sum divided by
the number of masked pixels over *all* ranks (one all-reduce of a count per step) times W, so
DDP's gradient average is exactly the gradient of one process's step over the same crops.
"""

from __future__ import annotations

import copy
import json
import logging
import math
import os
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..calibration.intrinsic import IntrinsicCalibration
from ..correction.fcn import (
    FCNArchitecture,
    FCNCorrectionModel,
    ResidualFCN,
    fcn_inputs,
    gaussian_nll,
    pad_to_multiple,
    run_fcn,
)
from ..correction.pipeline import correct
from ..correction.weights import save_weights
from ..errors import InputError, WeightsError
from ..evaluation.uncertainty import WRONG_MM, coverage, flag_precision_recall
from ..frame import ToFFrame
from .distributed import (
    Ranks,
    barrier,
    check_in_step,
    finish,
    rank_batch_size,
    shard_pixels,
    start,
    sum_over_ranks,
    wrap,
)
from .samples import check_training_frames, frames_digest
from .trainer import CHECKPOINT_NAME, load_checkpoint, save_checkpoint, split_frames

log = logging.getLogger(__name__)

#: |error| above which a pixel counts as unreliable in :func:`evaluate_fcn`, mm
UNRELIABLE_MM = WRONG_MM
#: validation and evaluation run on this many whole frames at a time
FRAMES_PER_CHUNK = 8
#: learning-rate schedules of :class:`FCNTrainConfig`
SCHEDULES = ("cosine", "constant")
#: the Gaussian's share within 2 σ, which the σ recalibration matches
TWO_SIGMA_SHARE = 0.9545


@dataclass(frozen=True)
class FCNTrainConfig:
    """Hyper-parameters of :func:`train_fcn`.

    Attributes:
        epochs: passes, each ``crops_per_frame`` crops of every training frame.
        batch_size: crops per Adam step.
        crop_px: side of the square crops, px (a frame smaller than that is used whole; the
            network pads to a multiple of ``architecture.multiple``).
        crops_per_frame: crops drawn per training frame and epoch.
        lr: Adam's (peak) learning rate.
        schedule: ``"cosine"`` (lr decayed to 0 over the run) or ``"constant"``.
        beta: β of the β-NLL (0 = the plain Gaussian NLL).
        recalibrate_sigma: fit the σ gain on the validation frames after training.
        weight_decay: Adam's L2 penalty.
        val_fraction: share of the frames (or groups) held out for validation (0: none).
        target_clip_mm: T, the target ``R* - R`` is clipped to +-T, mm.
        max_sigma_mm: stored in the model: pixels with a larger predicted σ are invalid in
            the corrected output.
        architecture: the network's shape.
        num_threads: torch intra-op threads while training (restored afterwards); None =
            leave as is.
    """

    epochs: int = 60
    batch_size: int = 8
    crop_px: int = 96
    crops_per_frame: int = 4
    lr: float = 1e-3
    schedule: str = "cosine"
    beta: float = 0.5
    recalibrate_sigma: bool = True
    weight_decay: float = 0.0
    val_fraction: float = 0.1
    target_clip_mm: float = 100.0
    max_sigma_mm: float = 20.0
    architecture: FCNArchitecture = field(default_factory=FCNArchitecture)
    num_threads: int | None = None

    def __post_init__(self) -> None:
        counts = (self.epochs, self.batch_size, self.crop_px, self.crops_per_frame)
        if any(not isinstance(n, (int, np.integer)) or n < 1 for n in counts):
            raise InputError("epochs, batch_size, crop_px and crops_per_frame must be integers "
                             f">= 1: {self}")
        if not (self.lr > 0 and self.weight_decay >= 0):
            raise InputError(f"need lr > 0 and weight_decay >= 0: {self}")
        if self.schedule not in SCHEDULES:
            raise InputError(f"schedule must be one of {SCHEDULES}, got {self.schedule!r}")
        if not 0 <= self.beta <= 1:
            raise InputError(f"beta must be in [0, 1], got {self.beta}")
        if not 0 <= self.val_fraction < 1:
            raise InputError(f"val_fraction must be in [0, 1), got {self.val_fraction}")
        if not (self.target_clip_mm > 0 and self.max_sigma_mm > 0):
            raise InputError(f"target_clip_mm and max_sigma_mm must be > 0: {self}")
        if not isinstance(self.architecture, FCNArchitecture):
            raise InputError(f"architecture must be an FCNArchitecture, got "
                             f"{type(self.architecture).__name__}")
        if self.num_threads is not None and self.num_threads < 1:
            raise InputError(f"num_threads must be >= 1 or None, got {self.num_threads}")

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON data."""
        return {**asdict(self), "architecture": self.architecture.as_dict()}


@dataclass
class FCNTrainingData:
    """Frames prepared for :func:`train_fcn` (CPU).

    Attributes:
        inputs: (N, 4, H', W') float32 network inputs of the whole frames (padded).
        target: (N, H, W) float32 clipped target ``R* - R``, mm, 0 where not usable.
        usable: (N, H, W) bool: valid measurement and a reference.
        calibrated: (N, H, W) float32 calibrated range, mm (NaN = invalid).
        amplitude: (N, H, W) float32 amplitude.
        reference: (N, H, W) float32 reference range, mm (NaN = missing).
        digest: SHA-256 of the frames and the calibration.
    """

    inputs: torch.Tensor
    target: torch.Tensor
    usable: torch.Tensor
    calibrated: np.ndarray
    amplitude: np.ndarray
    reference: np.ndarray
    digest: str

    @property
    def n_frames(self) -> int:
        return int(self.usable.shape[0])

    @property
    def frame_shape(self) -> tuple[int, int]:
        return int(self.usable.shape[1]), int(self.usable.shape[2])


def prepare_fcn_data(frames: Sequence[ToFFrame], calibration: IntrinsicCalibration,
                     cfg: FCNTrainConfig) -> FCNTrainingData:
    """Calibrate the frames, their input planes and clipped targets.

    Raises:
        InputError: no frames, a frame without reference or of another size than the
            calibration, or no usable pixel at all.
    """
    check_training_frames(frames, calibration.shape)
    amp = np.stack([f.amplitude for f in frames]).astype(np.float32)
    ref = np.stack([f.reference_mm for f in frames]).astype(np.float32)
    calibrated = calibration.apply(np.stack([f.range_mm for f in frames]), amp)
    inputs, valid = fcn_inputs(calibrated, amp, cfg.architecture.multiple)
    with np.errstate(invalid="ignore"):
        t = ref - calibrated
    usable = valid & np.isfinite(t)
    if not usable.any():
        raise InputError("no pixel of the training frames has both a valid measurement and a "
                         "reference")
    t = np.where(usable, np.clip(t, -cfg.target_clip_mm, cfg.target_clip_mm), 0.0)
    return FCNTrainingData(inputs, torch.from_numpy(t.astype(np.float32)),
                           torch.from_numpy(usable), calibrated.astype(np.float32), amp, ref,
                           frames_digest(frames, calibration))


def crop_shape(frame_shape: tuple[int, int], crop_px: int) -> tuple[int, int]:
    """(h, w) of the crops of frames of ``frame_shape``: ``crop_px`` or the frame's side."""
    return min(crop_px, frame_shape[0]), min(crop_px, frame_shape[1])


def draw_crops(train_ids: Sequence[int], frame_shape: tuple[int, int], cfg: FCNTrainConfig,
               seed: int, epoch: int) -> torch.Tensor:
    """One epoch's crops, (M, 3) int64 rows ``(frame, top, left)`` in random order, drawn from
    a generator seeded by ``(seed, epoch)``."""
    gen = torch.Generator().manual_seed(seed * 1_000_003 + epoch)
    ch, cw = crop_shape(frame_shape, cfg.crop_px)
    frame = torch.as_tensor(list(train_ids), dtype=torch.int64).repeat_interleave(
        cfg.crops_per_frame)
    m = frame.numel()
    top = torch.randint(0, frame_shape[0] - ch + 1, (m,), generator=gen)
    left = torch.randint(0, frame_shape[1] - cw + 1, (m,), generator=gen)
    return torch.stack([frame, top, left], dim=1)[torch.randperm(m, generator=gen)]


def crop_batch(data: FCNTrainingData, crops: torch.Tensor, cfg: FCNTrainConfig
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(inputs (B, 6, h', w'), target (B, h, w), mask (B, h, w))`` of the crops; the inputs
    padded to the network's multiple as at inference (:func:`pad_to_multiple`)."""
    ch, cw = crop_shape(data.frame_shape, cfg.crop_px)
    rows = crops.tolist()
    x = torch.stack([data.inputs[f, :, y:y + ch, x0:x0 + cw] for f, y, x0 in rows])
    t = torch.stack([data.target[f, y:y + ch, x0:x0 + cw] for f, y, x0 in rows])
    m = torch.stack([data.usable[f, y:y + ch, x0:x0 + cw] for f, y, x0 in rows])
    return pad_to_multiple(x, cfg.architecture.multiple), t, m


def learning_rate(cfg: FCNTrainConfig, step: int, total_steps: int) -> float:
    """The learning rate of the ``step``-th Adam step (0-based) of a run of ``total_steps``."""
    if cfg.schedule == "constant":
        return cfg.lr
    return 0.5 * cfg.lr * (1.0 + math.cos(math.pi * min(step, total_steps) / max(total_steps, 1)))


def _step(model: torch.nn.Module, opt: torch.optim.Optimizer, x: torch.Tensor,
          t: torch.Tensor, m: torch.Tensor, ranks: Ranks, beta: float) -> tuple[float, float]:
    """One Adam step; returns (this rank's plain NLL sum, its masked pixels)."""
    corr, sigma = model(x, t.shape[-2:])
    weighted = gaussian_nll(corr, sigma, t, m, beta)
    n = float(m.sum())
    n_all = sum_over_ranks([n], ranks)[0]
    # one process: the mean itself (scale exactly 1); W ranks: this rank's share of the mean
    # over every rank's pixels, times W, which DDP's average divides out again
    loss = weighted * (n * ranks.world / max(n_all, 1.0))
    opt.zero_grad(set_to_none=True)
    loss.backward()
    opt.step()
    if beta:
        with torch.no_grad():
            weighted = gaussian_nll(corr, sigma, t, m)
    return float(weighted.item()) * n, n


def _run_epoch(model: torch.nn.Module, opt: torch.optim.Optimizer, data: FCNTrainingData,
               train_ids: list[int], cfg: FCNTrainConfig, seed: int, epoch: int, bar: Any,
               ranks: Ranks) -> dict[str, Any]:
    """One epoch over this rank's share of the epoch's crops; the returned loss and counts are
    over every rank."""
    crops = draw_crops(train_ids, data.frame_shape, cfg, seed, epoch)
    mine = crops[shard_pixels(torch.arange(crops.shape[0]), ranks)]
    batch = rank_batch_size(cfg.batch_size, ranks)
    per_epoch = -(-mine.shape[0] // batch)
    total = per_epoch * cfg.epochs
    dev = ranks.device
    model.train()
    nll_sum = n_pixels = 0.0
    t0 = time.perf_counter()
    for i, b0 in enumerate(range(0, mine.shape[0], batch)):
        x, t, m = crop_batch(data, mine[b0:b0 + batch], cfg)
        # channels-last: oneDNN's convolutions run ~1.5x faster on NHWC on the CPU
        x = x.contiguous(memory_format=torch.channels_last)
        for group in opt.param_groups:
            group["lr"] = learning_rate(cfg, epoch * per_epoch + i, total)
        s, n = _step(model, opt, x.to(dev), t.to(dev), m.to(dev), ranks, cfg.beta)
        nll_sum += s
        n_pixels += n
        bar.update(x.shape[0])
        bar.set_postfix(epoch=epoch + 1, nll=f"{nll_sum / max(n_pixels, 1):.3f}", refresh=False)
    seconds = time.perf_counter() - t0
    nll_sum, n_all, n_crops = sum_over_ranks([nll_sum, n_pixels, float(mine.shape[0])], ranks)
    return {"epoch": epoch + 1, "loss_nll": nll_sum / max(n_all, 1.0), "crops": int(n_crops),
            "pixels": int(n_all), "seconds": seconds,
            "crops_per_s": n_crops / seconds if seconds > 0 else math.nan}


def error_stats(before: np.ndarray, after: np.ndarray, sigma: np.ndarray,
                max_sigma_mm: float) -> dict[str, float]:
    """Accuracy and σ calibration over pixels.

    Args:
        before: (M,) error of the calibrated range, ``R - R*``, mm.
        after: (M,) error after the correction, mm.
        sigma: (M,) predicted σ, mm.
        max_sigma_mm: the model's invalidation threshold.

    Returns:
        ``pixels``; ``rmse_before_mm`` / ``rmse_after_mm``, ``mae_*``, ``within_{2,5,10}mm_*``
        (fractions); ``coverage_{1,2,3}sigma`` (fraction with ``|after| <= k σ``,
        :func:`~tof_mpd_ros.evaluation.uncertainty.coverage`); ``median_sigma_mm``;
        ``flagged_fraction`` (σ > ``max_sigma_mm``), ``flag_precision`` and ``flag_recall`` of
        "flagged" against "|after| > 10 mm" (NaN when undefined,
        :func:`~tof_mpd_ros.evaluation.uncertainty.flag_precision_recall`); and
        ``kept_rmse_mm``, the RMSE of the pixels not flagged.
    """
    before, after, sigma = (np.asarray(a, np.float64).reshape(-1) for a in (before, after, sigma))
    out: dict[str, float] = {"pixels": int(after.size)}
    if after.size == 0:
        return out
    for name, err in (("before", np.abs(before)), ("after", np.abs(after))):
        out[f"rmse_{name}_mm"] = float(np.sqrt(np.mean(err ** 2)))
        out[f"mae_{name}_mm"] = float(np.mean(err))
        for k in (2, 5, 10):
            out[f"within_{k}mm_{name}"] = float(np.mean(err <= k))
    for k, frac in coverage(after, sigma).items():
        out[f"coverage_{k}sigma"] = frac
    flags = flag_precision_recall(after, sigma, max_sigma_mm, UNRELIABLE_MM)
    kept = sigma <= max_sigma_mm
    out.update(median_sigma_mm=float(np.median(sigma)),
               flagged_fraction=flags["flagged_fraction"], flag_precision=flags["precision"],
               flag_recall=flags["recall"],
               kept_rmse_mm=float(np.sqrt(np.mean(after[kept] ** 2))) if kept.any()
               else math.nan)
    return out


def _nll(correction: np.ndarray, sigma: np.ndarray, target: np.ndarray) -> float:
    """Mean Gaussian NLL (nats per pixel), :func:`gaussian_nll` in float64."""
    t = [torch.from_numpy(np.asarray(a, np.float64)) for a in (correction, sigma, target)]
    return float(gaussian_nll(*t, torch.ones_like(t[0], dtype=torch.bool)))


def _predict_usable(net: ResidualFCN, data: FCNTrainingData, ids: list[int],
                    device: torch.device | str = "cpu") -> tuple[np.ndarray, ...]:
    """Whole frames ``ids`` through :func:`run_fcn`, as at inference: ``(before, after, sigma,
    correction, target)``, each (M,) over the usable pixels, mm (errors ``R - R*`` before and
    after the correction, the predicted σ, the correction and the clipped target)."""
    parts: list[list[np.ndarray]] = [[], [], [], [], []]
    for c0 in range(0, len(ids), FRAMES_PER_CHUNK):
        chunk = ids[c0:c0 + FRAMES_PER_CHUNK]
        cal, ref = data.calibrated[chunk], data.reference[chunk]
        corr, sigma, _ = run_fcn(net, cal, data.amplitude[chunk], device=device)
        ok = data.usable[chunk].numpy()
        for part, a in zip(parts, (cal - ref, cal + corr - ref, sigma, corr,
                                   data.target[chunk].numpy()), strict=True):
            part.append(a[ok])
    return tuple(np.concatenate(p) for p in parts)


def _validate(net: ResidualFCN, data: FCNTrainingData, val_ids: list[int],
              cfg: FCNTrainConfig, device: torch.device) -> dict[str, float]:
    """Validation metrics on whole frames through :func:`run_fcn` (see the module docstring)."""
    if not val_ids:
        return {}
    before, after, sigma, corr, target = _predict_usable(net, data, val_ids, device)
    s = error_stats(before, after, sigma, cfg.max_sigma_mm)
    if s["pixels"] == 0:
        return {}
    return {"val_rmse_before_mm": s["rmse_before_mm"], "val_rmse_mm": s["rmse_after_mm"],
            "val_within_5mm_before": s["within_5mm_before"],
            "val_within_5mm": s["within_5mm_after"], "val_nll": _nll(corr, sigma, target),
            **{f"val_coverage_{k}sigma": s[f"coverage_{k}sigma"] for k in (1, 2, 3)},
            "val_median_sigma_mm": s["median_sigma_mm"]}


def sigma_gain(error_mm: np.ndarray, sigma_mm: np.ndarray) -> float:
    """The factor on σ that puts ``TWO_SIGMA_SHARE`` of the errors within 2 σ.

    Args:
        error_mm: (M,) errors of the corrected range, mm.
        sigma_mm: (M,) predicted σ, mm (> 0).

    Raises:
        InputError: no pixel.
    """
    if error_mm.size == 0:
        raise InputError("no pixel to recalibrate sigma on")
    z = np.abs(np.asarray(error_mm, np.float64)) / np.asarray(sigma_mm, np.float64)
    return float(np.quantile(z, TWO_SIGMA_SHARE) / 2.0)


def recalibrate_sigma(net: ResidualFCN, data: FCNTrainingData, val_ids: list[int]) -> float:
    """Fit :func:`sigma_gain` on the validation frames (whole, through :func:`run_fcn`) and
    fold it into ``net``'s σ output scales; returns the gain."""
    _, after, sigma, _, _ = _predict_usable(net, data, val_ids)
    gain = sigma_gain(after, sigma)
    scale_sigma(net, gain)
    log.info("sigma recalibrated on %d validation frames: gain %.3f", len(val_ids), gain)
    return gain


def scale_sigma(net: ResidualFCN, gain: float) -> None:
    """Multiply ``net``'s predicted σ by ``gain`` (> 0) by folding it into the σ output's floor
    and scale: the correction is untouched and the weights file needs no new field."""
    if not gain > 0:
        raise InputError(f"a sigma gain must be > 0, got {gain}")
    a = net.architecture
    net.architecture = replace(a, sigma_floor_mm=a.sigma_floor_mm * gain,
                               sigma_scale_mm=a.sigma_scale_mm * gain)


def recalibrate_sigma_on_frames(model: FCNCorrectionModel, frames: Sequence[ToFFrame], *,
                                source: str = "") -> tuple[FCNCorrectionModel, dict[str, Any]]:
    """A copy of ``model`` whose σ is refitted (:func:`sigma_gain`) on ``frames`` with
    references, e.g. held-out reference frames of the camera and scenes it will run on.

    The trainer fits σ's gain on its own validation frames, which come from the training
    scenes and renderer; on another camera or another kind of scene the network's errors are
    larger than that σ says (docs/method.md §9). One gain on a few scenes of the camera's own
    kind fixes the level. The network's weights are unchanged, and ``max_sigma_mm`` (the σ above
    which a pixel takes a sure neighbour's side) is scaled by the same gain, so the same pixels
    are unsure and the corrected range is the same: only the reported σ changes.

    Returns:
        The recalibrated model (its ``metadata["sigma_recalibrations"]`` gains an entry) and a
        summary: ``gain``, ``frames``, ``pixels`` and the 1/2/3σ coverage on ``frames`` before
        and after (in-sample: measure on other frames with ``tof-mpd evaluate``).

    Raises:
        InputError: no frames, a frame without reference or of another size, or no pixel with
            both a valid measurement and a reference.
    """
    _, after, sigma = _frame_errors(model, frames)
    gain = sigma_gain(after, sigma)  # raises when no pixel is left
    net = copy.deepcopy(model.net)
    scale_sigma(net, gain)
    entry = {"gain": gain, "frames": len(frames), "pixels": int(after.size)}
    summary = {**entry, "coverage_before": coverage(after, sigma),
               "coverage_after": coverage(after, sigma * gain)}
    history = [*model.metadata.get("sigma_recalibrations", []), {**entry, "source": source}]
    return replace(model, net=net, max_sigma_mm=model.max_sigma_mm * gain,
                   metadata={**model.metadata, "sigma_recalibrations": history}), summary


def evaluate_fcn(model: FCNCorrectionModel, frames: Sequence[ToFFrame]) -> dict[str, float]:
    """Accuracy and σ calibration of ``model`` on whole frames with references, through
    :func:`~tof_mpd_ros.correction.pipeline.correct` (errors of the corrected range before the
    σ invalidation, ``range_f_mm``).

    Returns:
        ``frames`` plus :func:`error_stats` over every valid pixel with a reference.

    Raises:
        InputError: no frames, a frame without reference or of another size.
    """
    stats = error_stats(*_frame_errors(model, frames), model.max_sigma_mm)
    return {"frames": len(frames), **stats}


def _frame_errors(model: FCNCorrectionModel, frames: Sequence[ToFFrame]
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(before, after, sigma)``, each (M,) float over the valid pixels with a reference, mm:
    the errors of the calibrated range and of the network's own range (``range_f_mm``, before
    the σ gate), and the predicted σ; frames through :func:`correct`, as at inference."""
    check_training_frames(frames, model.shape)
    parts: list[list[np.ndarray]] = [[], [], []]
    for c0 in range(0, len(frames), FRAMES_PER_CHUNK):
        chunk = frames[c0:c0 + FRAMES_PER_CHUNK]
        ref = np.stack([f.reference_mm for f in chunk])
        res = correct(model, np.stack([f.range_mm for f in chunk]),
                      np.stack([f.amplitude for f in chunk]))
        ok = res.valid & np.isfinite(ref)
        for part, a in zip(parts, (res.calibrated_mm - ref, res.range_f_mm - ref, res.sigma_mm),
                           strict=True):
            part.append(a[ok])
    before, after, sigma = (np.concatenate(p) for p in parts)
    return before, after, sigma


def _fingerprint(cfg: FCNTrainConfig, seed: int, digest: str, val_ids: list[int],
                 world: int) -> str:
    """What a checkpoint must match to be resumed (see the module docstring)."""
    # a constant-rate run can be extended by more epochs; a cosine one is fitted to its length
    free = ("epochs", "num_threads") if cfg.schedule == "constant" else ("num_threads",)
    settings = {k: v for k, v in cfg.as_dict().items() if k not in free}
    run = {"kind": "fcn", "config": settings, "seed": seed, "data": digest, "val": val_ids,
           **({"world": world} if world > 1 else {})}
    return json.dumps(run, sort_keys=True)


def train_fcn(
    frames: Sequence[ToFFrame],
    calibration: IntrinsicCalibration,
    config: FCNTrainConfig | None = None,
    *,
    seed: int = 0,
    groups: Sequence[int] | None = None,
    checkpoint_dir: str | os.PathLike[str] | None = None,
    weights_path: str | os.PathLike[str] | None = None,
    overwrite: bool = False,
    progress: bool = True,
    distributed: bool | None = None,
) -> tuple[FCNCorrectionModel, list[dict[str, Any]]]:
    """Train the fcn kind on frames with references (in one process, or data-parallel over the
    processes of a torchrun launch: :mod:`.distributed`).

    Args:
        frames: ToF frames (H, W as the calibration) with ``reference_mm`` (NaN = missing,
            excluded).
        calibration: intrinsic calibration, applied to every frame first.
        config: hyper-parameters (default :class:`FCNTrainConfig`).
        seed: seeds the network initialisation, the validation split and every epoch's crops.
        groups: (N,) group id per frame (e.g. scene) for the validation split: a group is held
            out as a whole. None = split by frame.
        checkpoint_dir: write ``checkpoint.pt`` here after every epoch and resume from it.
        weights_path: also write the final model there (:func:`save_weights`).
        overwrite: allow replacing an existing ``weights_path``.
        progress: show a tqdm bar with the running NLL (rank 0's, when distributed).
        distributed: train data-parallel over the torchrun processes (every rank calls
            ``train_fcn`` with the same frames; rank 0 writes the checkpoint and weights);
            None = when launched by torchrun with more than one process.

    Returns:
        ``(model, history)``: the trained model (on the CPU) and one dict per epoch (train NLL,
        validation metrics, seconds).

    Raises:
        InputError: bad frames or configuration. WeightsError: unusable checkpoint, or
        ``weights_path`` exists without ``overwrite`` (checked before training).
    """
    cfg = FCNTrainConfig() if config is None else config
    if not isinstance(cfg, FCNTrainConfig):
        raise InputError(f"config must be an FCNTrainConfig, got {type(cfg).__name__}")
    if weights_path is not None and Path(weights_path).exists() and not overwrite:
        # Refuse before training, not after an hour of it.
        raise WeightsError(f"weights file {weights_path} exists; pass overwrite=True to "
                           "replace it")
    ranks = start(distributed)
    try:
        return _train_fcn(frames, calibration, cfg, ranks, seed=seed, groups=groups,
                          checkpoint_dir=checkpoint_dir, weights_path=weights_path,
                          overwrite=overwrite, progress=progress)
    finally:
        finish(ranks)


def _resume(checkpoint_dir: str | os.PathLike[str] | None, net: torch.nn.Module,
            opt: torch.optim.Optimizer, fingerprint: str
            ) -> tuple[Path | None, int, list[dict[str, Any]]]:
    """(checkpoint path or None, epochs done, history) after resuming from a checkpoint."""
    if checkpoint_dir is None:
        return None, 0, []
    ckpt = Path(checkpoint_dir) / CHECKPOINT_NAME
    ckpt.parent.mkdir(parents=True, exist_ok=True)
    if not ckpt.exists():
        return ckpt, 0, []
    done, history = load_checkpoint(ckpt, net, opt, fingerprint)
    log.info("resuming from %s after epoch %d", ckpt, done)
    return ckpt, done, history


def _train_fcn(frames: Sequence[ToFFrame], calibration: IntrinsicCalibration,
               cfg: FCNTrainConfig, ranks: Ranks, *, seed: int, groups: Sequence[int] | None,
               checkpoint_dir: str | os.PathLike[str] | None,
               weights_path: str | os.PathLike[str] | None, overwrite: bool, progress: bool
               ) -> tuple[FCNCorrectionModel, list[dict[str, Any]]]:
    from tqdm import tqdm

    data = prepare_fcn_data(frames, calibration, cfg)
    train_ids, val_ids = split_frames(data.n_frames, cfg.val_fraction, seed, groups)
    rank_batch_size(cfg.batch_size, ranks)  # a batch that does not divide: refuse now
    model = FCNCorrectionModel.untrained(calibration, cfg.architecture, seed=seed,
                                         max_sigma_mm=cfg.max_sigma_mm)
    net = model.net.to(memory_format=torch.channels_last)
    ddp = wrap(net, ranks)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    fingerprint = _fingerprint(cfg, seed, data.digest, val_ids, ranks.world)
    ckpt, done, history = _resume(checkpoint_dir, net, opt, fingerprint)
    per_epoch = len(train_ids) * cfg.crops_per_frame // ranks.world
    threads = torch.get_num_threads()
    if cfg.num_threads is not None:
        torch.set_num_threads(cfg.num_threads)
    try:
        with tqdm(total=per_epoch * max(cfg.epochs - done, 0), unit="crop", desc="train fcn",
                  disable=not (progress and ranks.main)) as bar:
            for epoch in range(done, cfg.epochs):
                stats = _run_epoch(ddp, opt, data, train_ids, cfg, seed, epoch, bar, ranks)
                stats.update(_validate(net, data, val_ids, cfg, ranks.device))
                history.append(stats)
                log.info("epoch %d: %s", epoch + 1, stats)
                if ckpt is not None and ranks.main:
                    save_checkpoint(ckpt, net, opt, epoch + 1, history, fingerprint)
                barrier(ranks)  # no rank runs ahead of the checkpoint it may resume from
    finally:
        torch.set_num_threads(threads)
    check_in_step(net, ranks)
    net.to("cpu", memory_format=torch.contiguous_format)
    net.eval()
    gain = (recalibrate_sigma(net, data, val_ids) if cfg.recalibrate_sigma and val_ids
            else 1.0)
    model.metadata = {"training_data_digest": data.digest, "seed": seed,
                      "train_config": cfg.as_dict(), "n_frames": data.n_frames,
                      "train_frames": len(train_ids), "val_frames": val_ids,
                      "sigma_gain": gain, "final": history[-1] if history else {}}
    if weights_path is not None and ranks.main:
        save_weights(weights_path, model, training_data_digest=data.digest, overwrite=overwrite)
    return model, history


__all__ = ["FCNTrainConfig", "FCNTrainingData", "crop_batch", "draw_crops", "error_stats",
           "evaluate_fcn", "learning_rate", "prepare_fcn_data", "recalibrate_sigma",
           "recalibrate_sigma_on_frames", "scale_sigma", "sigma_gain", "train_fcn"]
