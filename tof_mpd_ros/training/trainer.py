"""Offline training of F and G (paper §III, §V): SGD with momentum, batch 500, 40 epochs.

``train(frames, calibration, config, seed=...)`` prepares the frames (calibration, targets,
ground-truth edges, see :mod:`.samples`), splits them by frame (or by caller-given groups such as
scenes) into training and validation sets, and trains both networks on one stream of patches:

* F minimises the squared error between its normalised output and ``t / T`` (the paper's
  Euclidean loss on the target truncated to +-T; the paper's T = 15 mm; by default one F per
  candidate T — 15, 30 and the data's own — trains on the same patches and the one most often
  within 5 mm on the validation pixels is kept);
* each G head k minimises the cross entropy of "group k" vs "anything else". Edge pixels are
  rare (a few percent, spread over four groups), so by default (``boundary_balance="balanced"``)
  each head weights its positives by ``0.5 / pi_k`` and its negatives by ``0.5 / (1 - pi_k)``
  (pi_k = fraction of group-k pixels in the training set): both classes carry half of the
  expected loss, as if sampled 50/50, without duplicating patches; the positive weight is capped
  at ``max_positive_weight`` to keep SGD steps bounded.

Both losses are summed and back-propagated once per batch (their parameters are disjoint, so
this equals two separate optimisers, with one autograd pass). Every epoch draws its pixels and
their order from a generator seeded by ``(seed, epoch)``, which makes runs deterministic and a
resumed run identical to an uninterrupted one: the checkpoint (``checkpoint.pt``, tensors and
plain data only, loaded with ``weights_only=True``) holds the networks, the momentum buffers,
the history and a fingerprint of the run it belongs to.

Sampling (issue 8: MD-scale training in <= 30 min on 2 cores): by default each epoch draws
``max_samples_per_frame = 4000`` of a frame's usable pixels (a new uniform draw without
replacement per frame and epoch), not all ~18.5 k the paper used. Over 40 epochs every pixel is
still seen ~9 times on MD-Train (486 x 4000 x 40 = 78 M SGD patch steps instead of 360 M), and
each epoch covers every frame, so the frame diversity that matters is kept. Measured cost on the
simulated small set (24 train frames, 40 epochs, seed 0, evaluated with the full pipeline on 12
MD-Test frames): R_F RMSE 6.84 vs 6.91 mm (all pixels), final RMSE 7.54 vs 7.64 mm, within 5 mm
90.1 vs 89.7 %, edges (1-px tolerance) precision 0.61 vs 0.51, recall 0.84 vs 0.87; i.e. no
accuracy loss within the noise of one seed, at 6x fewer steps. ``max_samples_per_frame=None``
restores the paper's every-pixel epochs (CLI: the ``tof-mpd train`` default still passes None;
see ``--max-samples-per-frame``).
"""

from __future__ import annotations

import copy
import json
import logging
import math
import os
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as tnf

from ..atomic_file import write_atomically
from ..calibration.intrinsic import IntrinsicCalibration
from ..correction.encoding import EncodingConfig
from ..correction.networks import N_ORIENTATIONS, RangeRecoveryNet
from ..correction.pipeline import CorrectionModel, GeodesicParams
from ..correction.weights import save_weights
from ..errors import InputError, WeightsError
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
from .edge_thresholds import choose_edge_thresholds, with_thresholds
from .samples import (
    TrainingData,
    auto_encoding,
    interior_clip_mm,
    prepare_training_data,
    sample_pixels,
)

log = logging.getLogger(__name__)

CHECKPOINT_NAME = "checkpoint.pt"
#: truncations tried by default (None = from the training data), chosen on validation data
DEFAULT_CLIP_CANDIDATES: tuple[float | None, ...] = (15.0, 30.0, None)
BALANCE_MODES = ("balanced", "none")


@dataclass(frozen=True)
class TrainConfig:
    """Training hyper-parameters (paper: SGD, momentum 0.9, batch 500, 40 epochs).

    Attributes:
        epochs: passes over the sampled training pixels.
        batch_size: patches per SGD step.
        lr_range, lr_boundary: learning rates of F and of the G heads.
        momentum: SGD momentum.
        weight_decay: L2 penalty of both networks.
        target_clip_mm: T, truncation of the F target, mm (the paper: 15); None = from the
            training data (:func:`.samples.interior_clip_mm`: the 99th percentile of the
            distortion away from edges, at least 15); a tuple of such values = one F per
            candidate learns from the same patches (F is small; 3 candidates train at ~0.65×
            the patches/s of one) and the one most often within 5 mm on the validation pixels
            is kept. Default 15, 30 and the data's own: on the cell the data's 39 mm wins, on
            a path-traced camera with heavy metal interreflections 15 mm does
            (docs/results.md).
        max_samples_per_frame: pixels drawn per training frame and epoch, a new draw each
            epoch (default 4000: MD-scale training in ~10-15 min of CPU on 2 cores, see the
            module docstring for the accuracy check; None = every usable pixel, the paper's
            ~18.5 k per frame, ~4.5x longer).
        val_fraction: fraction of frames held out for validation (at least one when there are
            two or more frames; 0 disables validation).
        val_samples_per_frame: pixels per validation frame (fixed draw), None = all.
        boundary_balance: ``"balanced"`` or ``"none"`` (see the module docstring).
        max_positive_weight: cap of the G positive-class weight.
        auto_bins: set b_R / b_A intervals from the training data's quantiles.
        chunk_batches: batches encoded at once (amortises the gather; memory ~ chunk * batch *
            1.1 kB).
        prefetch: gather the next chunk on a worker thread while the current one trains.
        num_threads: torch intra-op threads while training (restored afterwards); None = leave
            as is. Batch-500 GEMMs gain little from more threads, so 1 thread for SGD plus the
            prefetch thread is the best use of a 2-core machine.
        tune_edge_thresholds: after training, choose G's hysteresis thresholds on the
            validation frames by the full pipeline's accuracy in the boundary region
            (:mod:`.edge_thresholds`); False = the paper's 0.3 / 0.6.
    """

    epochs: int = 40
    batch_size: int = 500
    lr_range: float = 0.05
    lr_boundary: float = 0.05
    momentum: float = 0.9
    weight_decay: float = 0.0
    target_clip_mm: float | tuple[float | None, ...] | None = DEFAULT_CLIP_CANDIDATES
    max_samples_per_frame: int | None = 4000
    val_fraction: float = 0.1
    val_samples_per_frame: int | None = 4000
    boundary_balance: str = "balanced"
    max_positive_weight: float = 50.0
    auto_bins: bool = True
    chunk_batches: int = 40
    prefetch: bool = True
    num_threads: int | None = 1
    tune_edge_thresholds: bool = True

    @property
    def clip_candidates(self) -> tuple[float | None, ...]:
        """``target_clip_mm`` as a tuple of candidates."""
        t = self.target_clip_mm
        return tuple(t) if isinstance(t, (tuple, list)) else (t,)

    def __post_init__(self) -> None:
        if self.epochs < 1 or self.batch_size < 1 or self.chunk_batches < 1:
            raise InputError(f"epochs, batch_size and chunk_batches must be >= 1: {self}")
        if not (self.lr_range > 0 and self.lr_boundary > 0 and 0 <= self.momentum < 1):
            raise InputError(f"need lr > 0 and 0 <= momentum < 1: {self}")
        if not 0 <= self.val_fraction < 1:
            raise InputError(f"val_fraction must be in [0, 1), got {self.val_fraction}")
        if not self.clip_candidates or any(t is not None and not t > 0
                                           for t in self.clip_candidates):
            raise InputError(f"target truncations must be > 0 (or None = from the data): {self}")
        if self.boundary_balance not in BALANCE_MODES:
            raise InputError(f"boundary_balance must be one of {BALANCE_MODES}, "
                             f"got {self.boundary_balance!r}")


def split_frames(n: int, val_fraction: float, seed: int,
                 groups: Sequence[int] | None = None) -> tuple[list[int], list[int]]:
    """Seeded split of frame indices into (train, validation).

    Args:
        n: number of frames.
        val_fraction: share of the groups held out.
        seed: seeds the permutation.
        groups: (n,) group id per frame (e.g. the scene); a group goes to one side as a whole,
            so views of one scene never straddle the split. None = every frame its own group.

    Returns:
        Sorted frame indices ``(train, validation)``; validation is never empty when
        ``val_fraction > 0`` and there are two or more groups.
    """
    if n == 0:
        return [], []
    ids = list(range(n)) if groups is None else [int(g) for g in groups]
    if len(ids) != n:
        raise InputError(f"groups must give one id per frame: {n} frames, {len(ids)} ids")
    unique = sorted(set(ids))
    order = np.random.default_rng(seed).permutation(len(unique)).tolist()
    n_val = 0 if val_fraction == 0 or len(unique) < 2 else max(1, round(len(unique) *
                                                                         val_fraction))
    held_out = {unique[i] for i in order[:n_val]}
    return ([i for i in range(n) if ids[i] not in held_out],
            [i for i in range(n) if ids[i] in held_out])


class _Nets(torch.nn.Module):
    """F and G side by side, so one backward pass and one optimiser serve both. With several
    truncation candidates, one F per candidate (``range_net`` is the first; the others, seeded
    apart, in ``other_range_nets``) learns from the same patches."""

    def __init__(self, model: CorrectionModel, others: Sequence[RangeRecoveryNet] = ()) -> None:
        super().__init__()
        self.range_net = model.range_net
        self.boundary_nets = model.boundary_nets
        self.other_range_nets = torch.nn.ModuleList(others)

    @property
    def range_heads(self) -> list[RangeRecoveryNet]:
        return [self.range_net, *self.other_range_nets]

    def forward(self, feats: torch.Tensor) -> tuple[list[torch.Tensor], torch.Tensor]:
        """Every F head's normalised output (B,) and the G logits (B, 4, 2) of ``feats``
        (B, n_features): one forward through this module, as DDP needs."""
        return [f.normalised(feats) for f in self.range_heads], self.boundary_nets(feats)


def _class_weights(data: TrainingData, flat: torch.Tensor, cfg: TrainConfig) -> torch.Tensor:
    """(2, 4) loss weights indexed by [label, head] (see the module docstring)."""
    weights = torch.ones(2, N_ORIENTATIONS)
    if cfg.boundary_balance == "none" or flat.numel() == 0:
        return weights
    groups = data.group.reshape(-1)[flat].long()
    for k in range(N_ORIENTATIONS):
        pi = float((groups == k).float().mean())
        if 0 < pi < 1:
            weights[1, k] = min(0.5 / pi, cfg.max_positive_weight)
            weights[0, k] = 0.5 / (1 - pi)
    return weights


def _losses(model: torch.nn.Module, clips: Sequence[float], feats: torch.Tensor,
            target: torch.Tensor, group: torch.Tensor, weights: torch.Tensor
            ) -> tuple[torch.Tensor, torch.Tensor]:
    """(F loss, G loss) of one batch: MSE on clip(t, ±T) / T summed over the F heads (each its
    own T in ``clips``), weighted cross entropy averaged over the G heads. ``model`` is the
    :class:`_Nets` or its DDP wrapper."""
    f_out, logits = model(feats)                                         # [(B,)], (B, 4, 2)
    loss_f = sum(tnf.mse_loss(out, target.clamp(-t, t) / t)
                 for out, t in zip(f_out, clips, strict=True))
    orientations = torch.arange(N_ORIENTATIONS, device=feats.device)
    labels = (group[:, None] == orientations).long()                     # (B, 4)
    ce = tnf.cross_entropy(logits.reshape(-1, 2), labels.reshape(-1), reduction="none")
    w = weights[labels, orientations]
    return loss_f, (ce * w.reshape(-1)).mean()


def _clips(nets: _Nets) -> list[float]:
    return [f.target_clip_mm for f in nets.range_heads]


def _chunks(data: TrainingData, flat: torch.Tensor, size: int, prefetch: bool
            ) -> Iterator[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
    """Encoded chunks of ``flat`` in order; with ``prefetch`` the next chunk is gathered on a
    worker thread while the current one trains (torch ops release the GIL), which hides the
    gather on a 2-core machine. The result is identical either way."""
    starts = range(0, flat.numel(), size)
    if not prefetch:
        for c0 in starts:
            yield data.gather(flat[c0:c0 + size])
        return
    with ThreadPoolExecutor(max_workers=1) as pool:
        pending = None
        for c0 in starts:
            nxt = pool.submit(data.gather, flat[c0:c0 + size])
            if pending is not None:
                yield pending.result()
            pending = nxt
        if pending is not None:
            yield pending.result()


def _epoch_generator(seed: int, epoch: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed * 1_000_003 + epoch)


def _run_epoch(model: torch.nn.Module, clips: Sequence[float], opt: torch.optim.Optimizer,
               data: TrainingData, train_ids: list[int], weights: torch.Tensor,
               cfg: TrainConfig, seed: int, epoch: int, bar: Any, ranks: Ranks
               ) -> dict[str, float]:
    """One epoch of SGD over this rank's share of the epoch's pixels (all of them in one
    process); the losses and counts in the returned stats are over every rank."""
    flat = shard_pixels(sample_pixels(data, train_ids, cfg.max_samples_per_frame,
                                      _epoch_generator(seed, epoch)), ranks)
    batch = rank_batch_size(cfg.batch_size, ranks)
    dev = ranks.device
    weights = weights.to(dev)
    model.train()
    sum_f = sum_g = 0.0
    n_seen = 0
    t0 = time.perf_counter()
    for feats, target, group in _chunks(data, flat, batch * cfg.chunk_batches, cfg.prefetch):
        feats, target, group = feats.to(dev), target.to(dev), group.to(dev)
        for b0 in range(0, feats.shape[0], batch):
            sl = slice(b0, b0 + batch)
            loss_f, loss_g = _losses(model, clips, feats[sl], target[sl], group[sl], weights)
            opt.zero_grad(set_to_none=True)
            (loss_f + loss_g).backward()
            opt.step()
            n = feats[sl].shape[0]
            sum_f += loss_f.item() * n
            sum_g += loss_g.item() * n
            n_seen += n
        bar.update(feats.shape[0])
        bar.set_postfix(epoch=epoch + 1, loss_f=f"{sum_f / max(n_seen, 1):.4f}",
                        loss_g=f"{sum_g / max(n_seen, 1):.4f}", refresh=False)
    seconds = time.perf_counter() - t0
    sum_f, sum_g, n_all = sum_over_ranks([sum_f, sum_g, float(n_seen)], ranks)
    n_all = int(n_all)
    return {"epoch": epoch + 1, "loss_range": sum_f / max(n_all, 1),
            "loss_boundary": sum_g / max(n_all, 1), "patches": n_all, "seconds": seconds,
            "patches_per_s": n_all / seconds if seconds > 0 else math.nan}


@torch.no_grad()
def _validate(nets: _Nets, data: TrainingData, flat: torch.Tensor, weights: torch.Tensor,
              cfg: TrainConfig) -> dict[str, float]:
    """Validation metrics on the pixels ``flat``: range errors before/after F (untruncated
    reference, mm), the fraction within 5 mm (the paper's metric), G loss, and per-pixel edge
    recall / precision of the heads at probability 0.5 (before non-maximum suppression)."""
    if flat.numel() == 0:
        return {}
    nets.eval()
    heads = nets.range_heads
    err_before, loss_g, hits, positives, fired = [], 0.0, 0, 0, 0
    err_after: list[list[torch.Tensor]] = [[] for _ in heads]
    for c0 in range(0, flat.numel(), 20_000):
        idx = flat[c0:c0 + 20_000]
        feats, target, group = data.gather(idx)
        r = data.calibrated.reshape(-1)[idx]
        ref = data.reference.reshape(-1)[idx]
        err_before.append(r - ref)
        for errs, f in zip(err_after, heads, strict=True):
            errs.append(r + f(feats) - ref)
        _, lg = _losses(nets, _clips(nets), feats, target, group, weights)
        loss_g += float(lg) * idx.numel()
        fires = nets.boundary_nets.probabilities(feats) > 0.5                 # (M, 4)
        on_edge = group >= 0
        positives += int(on_edge.sum())
        hits += int(fires[on_edge, group[on_edge]].sum())
        fired += int(fires.sum())
    before, after = torch.cat(err_before), torch.cat(err_after[0])
    within = [float((torch.cat(e).abs() < 5).float().mean()) for e in err_after]
    return {"val_rmse_before_mm": float(before.square().mean().sqrt()),
            "val_rmse_mm": float(after.square().mean().sqrt()),
            "val_within_5mm_before": float((before.abs() < 5).float().mean()),
            "val_within_5mm": float((after.abs() < 5).float().mean()),
            "val_loss_boundary": loss_g / flat.numel(),
            "val_edge_recall": hits / positives if positives else math.nan,
            "val_edge_precision": hits / fired if fired else math.nan,
            "val_within_5mm_per_clip": {str(f.target_clip_mm): w
                                        for f, w in zip(heads, within, strict=True)}}


def _resolve_clips(cfg: TrainConfig, data: TrainingData) -> list[float]:
    """The F heads' truncations: ``target_clip_mm``'s candidates, ``None`` resolved from the
    data (:func:`.samples.interior_clip_mm`), duplicates dropped."""
    wanted = cfg.clip_candidates
    auto = None
    out: list[float] = []
    for t in wanted:
        if t is None:
            if auto is None:
                usable = data.usable.numpy()
                auto = interior_clip_mm(data.calibrated.numpy(), data.reference.numpy(), usable,
                                        data.group.numpy() >= 0)
            t = auto
        if float(t) not in out:
            out.append(float(t))
    return out


def _best_head(nets: _Nets, scores: dict[str, float]) -> RangeRecoveryNet:
    """The F head most often within 5 mm on the validation pixels (the first without them)."""
    heads = nets.range_heads
    if len(heads) > 1 and scores:
        best = max(heads, key=lambda f: scores.get(str(f.target_clip_mm), -1.0))
        log.info("F truncation chosen on the validation frames: +-%.0f mm (%s)",
                 best.target_clip_mm, ", ".join(f"{t}: {w:.3f}" for t, w in scores.items()))
        return best
    if len(heads) > 1:
        log.warning("several F truncations but no validation frames: keeping the first")
    return heads[0]


def _fingerprint(cfg: TrainConfig, seed: int, data: TrainingData, val_ids: list[int],
                 world: int = 1) -> str:
    """What a checkpoint must match to be resumed. ``epochs`` is left out on purpose: nothing
    depends on it (no schedule), so a finished run can be extended by asking for more epochs;
    ``chunk_batches``, ``prefetch`` and ``num_threads`` change speed, not the maths. The
    number of processes (``world``) changes how an epoch's pixels are dealt out, so a
    distributed run resumes only with as many."""
    settings = {k: v for k, v in asdict(cfg).items()
                if k not in ("epochs", "chunk_batches", "prefetch", "num_threads",
                             "tune_edge_thresholds")}
    run = {"config": settings, "seed": seed, "data": data.digest, "val": val_ids,
           "encoding": data.encoding.as_dict(), **({"world": world} if world > 1 else {})}
    return json.dumps(run, sort_keys=True)


def save_checkpoint(path: Path, nets: torch.nn.Module, opt: torch.optim.Optimizer, epoch: int,
                    history: list[dict[str, Any]], fingerprint: str) -> None:
    """Write what :func:`load_checkpoint` resumes from (atomically): the networks' and the
    optimiser's state, the epochs done, the history (plain data: numbers, strings, lists and
    dicts of them, as ``weights_only=True`` loads) and the run's fingerprint. Used by both
    trainers (:mod:`.fcn_trainer` too)."""
    state = {"epoch": epoch, "nets": nets.state_dict(), "optimizer": opt.state_dict(),
             "history": history, "fingerprint": fingerprint}
    write_atomically(path, lambda stream: torch.save(state, stream))


def load_checkpoint(path: Path, nets: torch.nn.Module, opt: torch.optim.Optimizer,
                    fingerprint: str) -> tuple[int, list[dict[str, Any]]]:
    """Restore a checkpoint into ``nets`` and ``opt``; returns (epochs done, history).

    Raises:
        WeightsError: the checkpoint's fingerprint is not ``fingerprint`` (another run), or it
            cannot be read.
    """
    try:
        state = torch.load(path, weights_only=True, map_location="cpu")
        if state["fingerprint"] != fingerprint:
            raise WeightsError(f"checkpoint {path} belongs to another run (different data, "
                               "config or seed); remove it or use another checkpoint_dir")
        nets.load_state_dict(state["nets"])
        opt.load_state_dict(state["optimizer"])
        return int(state["epoch"]), list(state["history"])
    except WeightsError:
        raise
    except Exception as err:  # unpickling/zip/key errors: any unreadable checkpoint
        raise WeightsError(f"checkpoint {path} is unreadable (corrupt or truncated?): "
                           f"{type(err).__name__}: {err}") from err


def train(
    frames: Sequence[ToFFrame],
    calibration: IntrinsicCalibration,
    config: TrainConfig | None = None,
    *,
    seed: int = 0,
    encoding: EncodingConfig | None = None,
    geodesic: GeodesicParams | None = None,
    groups: Sequence[int] | None = None,
    checkpoint_dir: str | os.PathLike[str] | None = None,
    weights_path: str | os.PathLike[str] | None = None,
    overwrite: bool = False,
    progress: bool = True,
    distributed: bool | None = None,
) -> tuple[CorrectionModel, list[dict[str, float]]]:
    """Train F and G on frames with references (in one process, or data-parallel over the
    processes of a torchrun launch: :mod:`.distributed`).

    Args:
        frames: ToF frames (H, W as the calibration) with ``reference_mm`` (NaN = missing,
            excluded).
        calibration: intrinsic calibration, applied to every frame first.
        config: hyper-parameters (default: the paper's).
        seed: seeds the network initialisation, the validation split and every epoch's sampling.
        encoding: encoding constants (default :class:`EncodingConfig`; bins set from the data
            when ``config.auto_bins``).
        geodesic: geodesic constants stored in the model.
        groups: (N,) group id per frame (e.g. scene) for the validation split: a group is held
            out as a whole. None = split by frame.
        checkpoint_dir: write ``checkpoint.pt`` here after every epoch and resume from it.
        weights_path: also write the final model there (see :func:`save_weights`).
        overwrite: allow replacing an existing ``weights_path``.
        progress: show a tqdm bar with the running losses (rank 0's, when distributed).
        distributed: train data-parallel over the torchrun processes (every rank calls
            ``train`` with the same frames; rank 0 writes the checkpoint and weights); None =
            when launched by torchrun with more than one process.

    Returns:
        ``(model, history)``: the trained model and one dict per epoch (losses, validation
        metrics, patches/s).

    Raises:
        InputError: bad frames or configuration. WeightsError: unusable checkpoint or weights
        path.
    """
    ranks = start(distributed)
    try:
        return _train(frames, calibration, config or TrainConfig(), ranks, seed=seed,
                      encoding=encoding, geodesic=geodesic, groups=groups,
                      checkpoint_dir=checkpoint_dir, weights_path=weights_path,
                      overwrite=overwrite, progress=progress)
    finally:
        finish(ranks)


# ~110 lines: one linear recipe (prepare, build, resume, epochs, pick, save) over shared state
# whose steps are already helpers; splitting it would only pass that state on.
def _train(frames: Sequence[ToFFrame], calibration: IntrinsicCalibration, cfg: TrainConfig,
           ranks: Ranks, *, seed: int, encoding: EncodingConfig | None,
           geodesic: GeodesicParams | None, groups: Sequence[int] | None,
           checkpoint_dir: str | os.PathLike[str] | None,
           weights_path: str | os.PathLike[str] | None, overwrite: bool, progress: bool
           ) -> tuple[CorrectionModel, list[dict[str, float]]]:
    from tqdm import tqdm

    if weights_path is not None and Path(weights_path).exists() and not overwrite:
        # Refuse before training, not after an hour of it.
        raise WeightsError(f"weights file {weights_path} exists; pass overwrite=True to "
                           "replace it")
    enc = encoding or EncodingConfig()
    if cfg.auto_bins:
        enc = auto_encoding(frames, calibration, enc)
    # targets untruncated here: each F head truncates them at its own T
    data = prepare_training_data(frames, calibration, enc, target_clip_mm=math.inf)
    clips = _resolve_clips(cfg, data)
    train_ids, val_ids = split_frames(data.n_frames, cfg.val_fraction, seed, groups)
    model = CorrectionModel.untrained(calibration, enc, seed=seed, geodesic=geodesic)
    model.range_net.target_clip_mm = clips[0]
    others = [RangeRecoveryNet(enc.n_features, target_clip_mm=t,
                               generator=torch.Generator().manual_seed(seed * 1009 + k))
              for k, t in enumerate(clips[1:], start=1)]
    log.info("F target truncated at +-%s mm", " / ".join(f"{t:.0f}" for t in clips))
    nets = _Nets(model, others)
    ddp = wrap(nets, ranks)
    opt = torch.optim.SGD(
        [{"params": [p for f in nets.range_heads for p in f.parameters()], "lr": cfg.lr_range},
         {"params": nets.boundary_nets.parameters(), "lr": cfg.lr_boundary}],
        momentum=cfg.momentum, weight_decay=cfg.weight_decay, foreach=True)
    all_train = sample_pixels(data, train_ids, None, torch.Generator().manual_seed(seed))
    weights = _class_weights(data, all_train, cfg)
    val_flat = sample_pixels(data, val_ids, cfg.val_samples_per_frame,
                             torch.Generator().manual_seed(seed + 1))
    fingerprint = _fingerprint(cfg, seed, data, val_ids, ranks.world)
    ckpt = Path(checkpoint_dir) / CHECKPOINT_NAME if checkpoint_dir is not None else None
    done, history = 0, []
    if ckpt is not None:
        ckpt.parent.mkdir(parents=True, exist_ok=True)
        if ckpt.exists():
            done, history = load_checkpoint(ckpt, nets, opt, fingerprint)
            log.info("resuming from %s after epoch %d", ckpt, done)
    per_frame = data.usable[train_ids].flatten(1).sum(1)
    if cfg.max_samples_per_frame is not None:
        per_frame = per_frame.clamp(max=cfg.max_samples_per_frame)
    per_epoch = int(per_frame.sum()) // ranks.world
    threads = torch.get_num_threads()
    if cfg.num_threads is not None:
        torch.set_num_threads(cfg.num_threads)
    try:
        with tqdm(total=per_epoch * (cfg.epochs - done), disable=not (progress and ranks.main),
                  unit="patch", unit_scale=True, desc="train F+G") as bar:
            for epoch in range(done, cfg.epochs):
                stats = _run_epoch(ddp, _clips(nets), opt, data, train_ids, weights, cfg, seed,
                                   epoch, bar, ranks)
                stats.update(_validate(_on_cpu(nets), data, val_flat, weights, cfg))
                history.append(stats)
                log.info("epoch %d: %s", epoch + 1, stats)
                if ckpt is not None and ranks.main:
                    save_checkpoint(ckpt, nets, opt, epoch + 1, history, fingerprint)
                barrier(ranks)  # no rank runs ahead of the checkpoint it may resume from
    finally:
        torch.set_num_threads(threads)
    check_in_step(nets, ranks)
    nets.to("cpu")
    nets.eval()
    clip_scores = history[-1].get("val_within_5mm_per_clip", {}) if history else {}
    model.range_net = _best_head(nets, clip_scores)
    edge_choice = None
    if cfg.tune_edge_thresholds and val_ids:
        edge_choice = choose_edge_thresholds(model, [frames[i] for i in val_ids])
        if edge_choice is not None:
            with_thresholds(model, edge_choice)
            lo, hi, boundary, _ = edge_choice.before
            log.info("G edge thresholds %.2f / %.2f: boundary within 5 mm %.3f (%.2f / %.2f: "
                     "%.3f, F alone: %.3f) on the validation frames", edge_choice.low,
                     edge_choice.high, max(r[2] for r in edge_choice.table), lo, hi, boundary,
                     edge_choice.f_alone[0])
    model.metadata = {"training_data_digest": data.digest, "seed": seed,
                      "train_config": asdict(cfg), "n_frames": data.n_frames,
                      "target_clip_mm": model.range_net.target_clip_mm,
                      "target_clip_validation": clip_scores,
                      "train_frames": len(train_ids), "val_frames": val_ids,
                      "final": history[-1] if history else {},
                      "edge_thresholds": None if edge_choice is None else edge_choice.as_dict()}
    if weights_path is not None and ranks.main:
        save_weights(weights_path, model, training_data_digest=data.digest, overwrite=overwrite)
    return model, history


def _on_cpu(nets: _Nets) -> _Nets:
    """``nets`` itself on a CPU, else a CPU copy (validation gathers its patches on the CPU)."""
    if next(nets.parameters()).device.type == "cpu":
        return nets
    return copy.deepcopy(nets).cpu()

