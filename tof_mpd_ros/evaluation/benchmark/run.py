"""Running the benchmark: tune the baselines on the training frames, then run every method on
the same test frames and pool the paper's metrics (the module doc of
:mod:`tof_mpd_ros.evaluation.benchmark` gives the protocol).

Either kind of model: the patch kind runs as F alone and the full method (``proposed``), the
fcn kind as one method, ``fcn``, in the same tables (:func:`.config.methods_for`); the
reference-edge ablation and F's truncation in the miss tally exist for the patch kind only."""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from ...correction.fcn import FCNCorrectionModel
from ...correction.geodesic import geodesic_filter
from ...correction.pipeline import CorrectionModel, check_frame_pair, correct
from ...errors import InputError
from ...frame import ToFFrame
from ..baselines import within_threshold
from ..components import ComponentTally, FrameStages
from ..diagnosis import MissTally, NoiseTally, RegionTally
from ..metrics import FrameAccumulator
from ..profiles import choose_boundary_line, sample_profile
from .config import (
    BASELINE_NAMES,
    F_ALONE,
    RANK_THRESHOLD_MM,
    REFERENCE_EDGES,
    BenchmarkConfig,
    GridSpec,
    default_grids,
    methods_for,
    own_method,
)
from .context import run_info
from .paper import compare_with_paper
from .result import BenchmarkResult
from .split import CalibratedFrame, TrainValSplit, calibrate_frames, split_train_val
from .tuning import TunedBaseline, tune_baseline

log = logging.getLogger(__name__)


def run_benchmark(model: CorrectionModel | FCNCorrectionModel, train_frames: Iterable[ToFFrame],
                  test_frames: Iterable[ToFFrame], config: BenchmarkConfig | None = None, *,
                  train_sources: Sequence[int] | None = None,
                  on_stage: Callable[[str], None] | None = None) -> BenchmarkResult:
    """Run every method on the same test frames (see the package doc for the protocol).

    Args:
        model: the correction model, either kind (calibration, F and G, or the fcn
            network); frames must be its crop.
        train_frames: training frames with references (for the learned baselines and the grid
            search), in capture order.
        test_frames: test frames; those without a reference are skipped (counted).
        config: settings (default :class:`BenchmarkConfig`).
        train_sources: (N,) recording index per training frame, for the session split.
        on_stage: called with a short message at each stage (the CLI prints it).

    Returns:
        The :class:`BenchmarkResult`.

    Raises:
        InputError: frames of the wrong crop, fewer than 2 training frames with a reference,
            no test frame with a reference, bad grids.
    """
    cfg = config or BenchmarkConfig()
    say = on_stage or (lambda msg: log.info("%s", msg))
    start = time.perf_counter()
    grids = cfg.grids if cfg.grids is not None else default_grids(model, quick=cfg.quick)
    say("calibrating the training frames")
    split, fit_frames, val_frames = _calibrated_split(model, train_frames, train_sources, cfg)
    timings = {"calibrate_train_s": time.perf_counter() - start}

    t0 = time.perf_counter()
    tuned = _tune(grids, fit_frames, val_frames, cfg.progress, say)
    hits = [within_threshold(f.range_mm, f.reference_mm) for f in val_frames]
    val_calibrated = sum(h for h, _ in hits) / max(1.0, sum(c for _, c in hits))
    del fit_frames, val_frames
    timings["tune_baselines_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    tests, skipped = _with_reference(test_frames)
    tally = _TestFrames(model, tuned, cfg, len(tests))
    say(f"running {len(tally.methods)} methods on {len(tests)} test frames")
    with _bar(len(tests), "benchmark test frames", cfg.progress) as bar:
        for index, frame in enumerate(tests):
            tally.add(index, frame)
            bar.update(1)
    timings["test_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    evaluations, diagnostics, evidence = tally.result(model, tuned, val_calibrated)
    components = tally.components.result()
    acc5 = {m: (ev.whole.at(RANK_THRESHOLD_MM), ev.boundary.at(RANK_THRESHOLD_MM))
            for m, ev in evaluations.items()}
    comparison = compare_with_paper(acc5, evidence, proposed=own_method(model.kind))
    timings["metrics_s"] = time.perf_counter() - t0
    timings["total_s"] = time.perf_counter() - start
    return BenchmarkResult(evaluations, tally.median_seconds(), tuned, components, split,
                           comparison, diagnostics, tally.examples, len(tests), skipped, timings,
                           run_info(model, cfg), model.kind)


def _with_reference(frames: Iterable[ToFFrame]) -> tuple[list[ToFFrame], int]:
    """The frames with a reference, and how many had none.

    Raises:
        InputError: no frame has a reference.
    """
    kept, skipped = [], 0
    for frame in frames:
        if frame.reference_mm is None:
            skipped += 1
        else:
            kept.append(frame)
    if not kept:
        raise InputError("no test frame has a reference to evaluate against")
    return kept, skipped


def _calibrated_split(model: CorrectionModel | FCNCorrectionModel, train_frames: Iterable[ToFFrame],
                      train_sources: Sequence[int] | None, cfg: BenchmarkConfig
                      ) -> tuple[TrainValSplit, list[CalibratedFrame], list[CalibratedFrame]]:
    """Calibrate the training frames with a reference and split them (indices of the split
    are into ``train_frames``); returns the split, the fit frames and the validation frames."""
    train = list(train_frames)
    keep = [i for i, f in enumerate(train) if f.reference_mm is not None]
    calibrated = dict(zip(keep, calibrate_frames(model, (train[i] for i in keep)), strict=True))
    sources = None if train_sources is None else list(train_sources)
    if sources is not None:
        sources = [sources[i] for i in keep]
    split = split_train_val([train[i].stamp_ns for i in keep], cfg.val_fraction,
                            sources=sources, gap_s=cfg.session_gap_s,
                            max_val_frames=cfg.max_val_frames)
    split = TrainValSplit(tuple(keep[i] for i in split.fit), tuple(keep[i] for i in split.val),
                          split.n_groups, split.how)
    return split, [calibrated[i] for i in split.fit], [calibrated[i] for i in split.val]


def _tune(grids: Mapping[str, GridSpec], fit_frames: list[CalibratedFrame],
          val_frames: list[CalibratedFrame], progress: bool,
          say: Callable[[str], None]) -> dict[str, TunedBaseline]:
    """Fit and grid-search every baseline of ``grids``, in :data:`BASELINE_NAMES` order."""
    names = [n for n in BASELINE_NAMES if n in grids]
    say(f"fitting and grid-searching {len(names)} baselines on {len(fit_frames)} fit / "
        f"{len(val_frames)} validation frames")
    tuned: dict[str, TunedBaseline] = {}
    with _bar(len(names), "tuning baselines", progress) as bar:
        for name in names:
            bar.set_postfix_str(name)
            tuned[name] = tune_baseline(name, grids[name], fit_frames, val_frames)
            log.debug("%s: chose %s (validation %.3f)", name, tuned[name].chosen,
                      tuned[name].val_score)
            bar.update(1)
    return tuned


def _bar(total: int, desc: str, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, disable=not enabled, file=sys.stderr, leave=True)


class _TestFrames:
    """Every method on each test frame, pooled: the stages through the one component loop
    (:class:`~..components.ComponentTally`), the baselines and (patch kind) F alone beside
    them, and the measurements the comparison with the paper quotes (regions, misses, noise,
    the patch kind's reference-edge ablation)."""

    def __init__(self, model: CorrectionModel | FCNCorrectionModel,
                 tuned: Mapping[str, TunedBaseline], cfg: BenchmarkConfig, n_frames: int) -> None:
        self.model, self.tuned, self.cfg = model, tuned, cfg
        self.patch = isinstance(model, CorrectionModel)
        self.methods = [m for m in methods_for(model.kind)
                        if m not in BASELINE_NAMES or m in tuned]
        # the benchmark's component analysis has no per-region or operating-point diagnostics
        self.components = ComponentTally(model, cfg.thresholds, diagnostics=False)
        self.accuracy = {m: FrameAccumulator(cfg.thresholds) for m in self.methods}
        self.seconds: dict[str, list[float]] = {m: [] for m in self.methods}
        self.ablation = FrameAccumulator(cfg.thresholds)
        self.regions = RegionTally(RANK_THRESHOLD_MM)
        # F's target truncation; the fcn kind has none (no pixel is out of its reach by design)
        clip = float(model.range_net.target_clip_mm) if self.patch else None
        self.misses = MissTally(clip, RANK_THRESHOLD_MM)
        self.noise = NoiseTally()
        self.n_evaluated = self.n_boundary = 0
        n_ex = min(cfg.n_examples, n_frames)
        # Evenly spread, distinct frames (different scenes in a multi-scene test set).
        self.example_index = ({(i + 1) * n_frames // (n_ex + 1) for i in range(n_ex)}
                              if n_frames > n_ex else set(range(n_frames)))
        self.examples: list[dict[str, Any]] = []

    def _run(self, r: np.ndarray, a: np.ndarray, reference: np.ndarray
             ) -> tuple[FrameStages, dict[str, np.ndarray], dict[str, float]]:
        """The stages, then every method's (H, W) float32 estimate in mm and wall time in s
        (calibration included after raw)."""
        tc = time.perf_counter()
        cal = self.model.calibration.apply(r, a)
        t_cal = time.perf_counter() - tc
        stages = self.components.add(r, a, reference)
        own = own_method(self.model.kind)
        est = {"raw": r.astype(np.float32), "calibrated": cal, own: stages.full.range_mm}
        times = {"raw": 0.0, "calibrated": t_cal, own: stages.seconds}
        if self.patch:
            tc = time.perf_counter()
            est[F_ALONE] = correct(self.model, r, a, use_boundary=False).range_mm
            times[F_ALONE] = time.perf_counter() - tc
        for name, tb in self.tuned.items():
            tc = time.perf_counter()
            est[name] = tb.method.apply(cal, a, **tb.apply_params)
            times[name] = t_cal + time.perf_counter() - tc
        return stages, est, times

    def add(self, index: int, frame: ToFFrame) -> None:
        """Run and pool test frame number ``index`` (it has a reference)."""
        r, a = check_frame_pair(self.model.shape, frame.range_mm, frame.amplitude)
        ref = frame.reference_mm
        assert ref is not None
        stages, est, times = self._run(r, a, ref)
        mask = stages.boundary
        for m in self.methods:
            self.accuracy[m].add(est[m], ref, mask)
            self.seconds[m].append(times[m])
        full = stages.full
        regions = dict(est)
        if self.patch:
            oracle = _with_reference_edges(self.model, full.range_f_mm, stages.gt_edges,
                                           full.range_mm)
            self.ablation.add(oracle, ref, mask)
            regions[REFERENCE_EDGES] = oracle
        self.regions.add(regions, ref, stages.edge_distance)
        self.misses.add(est, ref, est["calibrated"])
        self.noise.add(est["calibrated"], ref, mask)
        valid = np.isfinite(ref)
        self.n_evaluated += int(valid.sum())
        self.n_boundary += int((valid & mask).sum())
        if index in self.example_index:
            self.examples.append(_example(index, ref, a, est, full.edges, stages.gt_edges,
                                          self.cfg.profile_length_px))

    def median_seconds(self) -> dict[str, float]:
        """Method -> median wall time per frame, s."""
        return {m: float(np.median(v)) for m, v in self.seconds.items()}

    def result(self, model: CorrectionModel | FCNCorrectionModel,
               tuned: Mapping[str, TunedBaseline], val_calibrated: float
               ) -> tuple[dict, dict[str, Any], dict[str, Any]]:
        """Per method accuracy, the diagnostics written to the report and the evidence for
        :func:`~.paper.compare_with_paper`."""
        evaluations = {m: self.accuracy[m].result() for m in self.methods}
        noise = self.noise.to_dict()
        regions, misses = self.regions.result(), self.misses.result()
        oracle = self.ablation.result() if self.patch else None
        diagnostics = {"calibrated_error_away_from_boundaries": noise,
                       "boundary_share": (self.n_boundary / self.n_evaluated
                                          if self.n_evaluated else None),
                       "val_calibrated_within_5mm": val_calibrated,
                       "regions_within_5mm": regions, "misses": misses,
                       "ablation_reference_edges": None if oracle is None else oracle.to_dict()}
        meta = model.metadata if isinstance(model.metadata, dict) else {}
        evidence = {**noise, "boundary_share": diagnostics["boundary_share"],
                    "val_scores": {m: t.val_score for m, t in tuned.items()},
                    "val_calibrated": val_calibrated,
                    "rfd_training_pixels": tuned["RFD"].n_training_pixels() if "RFD" in tuned
                    else None,
                    "rfd_chosen": tuned["RFD"].chosen if "RFD" in tuned else None,
                    "f_training_patches": meta.get("final", {}).get("patches"),
                    "f_epochs": meta.get("train_config", {}).get("epochs"),
                    "regions": regions, "misses": misses,
                    "reference_edges": None if oracle is None else (
                        oracle.whole.at(RANK_THRESHOLD_MM), oracle.boundary.at(RANK_THRESHOLD_MM))}
        return evaluations, diagnostics, evidence


def _with_reference_edges(model: CorrectionModel, range_f_mm: np.ndarray, gt_edges: np.ndarray,
                          full_mm: np.ndarray) -> np.ndarray:
    """(H, W) float32 the full method's output had G found exactly the reference's edges: R_F
    geodesically filtered over ``gt_edges`` with the model's filter constants (NaN where the
    full method gives no answer)."""
    p = model.geodesic
    out = geodesic_filter(range_f_mm, gt_edges, k=p.k, sigma=p.sigma, step=p.step)
    return np.where(np.isfinite(full_mm), out, np.nan).astype(np.float32)


def _example(index: int, reference: np.ndarray, amplitude: np.ndarray,
             estimates: Mapping[str, np.ndarray], edges_g: np.ndarray, gt: np.ndarray,
             length_px: int) -> dict[str, Any]:
    """Arrays of one example frame and its range profile across a boundary."""
    line = choose_boundary_line(reference, gt, length_px=length_px)
    profiles: dict[str, np.ndarray] = {}
    if line is not None:
        profiles["reference"] = sample_profile(reference, line)
        for name, image in estimates.items():
            profiles[name] = sample_profile(image, line)
    return {"index": index, "reference": reference, "amplitude": amplitude,
            "estimates": dict(estimates), "edges_g": edges_g, "line": line,
            "profiles": profiles}
