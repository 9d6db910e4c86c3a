"""The paper's experiments (§V) side by side: raw, calibrated, the six baselines, F alone and the
full method on the same test frames.

Protocol (what :func:`run_benchmark` does):

1. Every frame — training and test — is cropped to the model's shape by the caller and calibrated
   with the model's per-pixel intrinsic calibration; every baseline works on the calibrated range,
   as in the paper.
2. The training frames are split into a *fit* part and a *validation* part
   (:func:`split_train_val`: whole capture sessions — runs of frames separated by a stamp gap,
   i.e. scenes in the simulated layout — go to validation, so validation views are of scenes the
   forests never saw). RF-WF and RFD are fitted on the fit part; every baseline's free
   parameters are grid-searched on the validation part with the paper's score (fraction of
   pixels within 5 mm). The grid, the chosen values and every combination's score are recorded.
   F and G are whatever the weights file holds (trained on all training frames by ``tof-mpd
   train``).
3. On each test frame with a reference: every method runs, timed per frame (calibration
   included for everything after raw); the accuracy curves (whole image, 5 px boundary region),
   MAE/RMSE, the component analysis (raw / calibrated / F / geodesic+G / full) and G-vs-Canny
   edge precision/recall are pooled over pixels of all frames.
4. Methods are ranked at 5 mm and the ranking is compared with the paper's (proposed first, RFD
   second, the other baselines marginally above calibrated, calibrated above raw); every
   difference carries the evidence measured here that explains it.

:func:`tof_mpd_ros.evaluation.report.write_benchmark_report` turns the result into
``results.json``, PNGs and ``index.html``.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import platform
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from ..correction.edges import canny_score_map, ground_truth_edges
from ..correction.geodesic import geodesic_filter
from ..correction.pipeline import CorrectionModel, check_frame_pair, correct
from ..errors import InputError
from ..frame import ToFFrame
from .baselines import BASELINES, Baseline, grid_search, within_threshold
from .baselines.forest import per_frame_quota
from .components import (
    CANNY_HIGHS_MM,
    G_THRESHOLDS,
    STAGES,
    ComponentEvaluation,
    g_edge_strength,
)
from .diagnosis import MissTally, RegionTally, edge_distance, local_mean
from .metrics import (
    DEFAULT_THRESHOLDS_MM,
    FrameAccumulator,
    FrameEvaluation,
    boundary_region,
    edge_precision_recall,
)
from .profiles import DEFAULT_LENGTH_PX, ProfileLine, choose_boundary_line, sample_profile

log = logging.getLogger(__name__)

BASELINE_NAMES: tuple[str, ...] = ("JBF", "WMF", "RF-WF", "RFD", "TV", "PD")
PROPOSED = "proposed"
F_ALONE = "F"
#: the ablation: the full method with the reference's edges in place of G's
REFERENCE_EDGES = "full, reference edges"
# Every method in report order; the paper's Fig. 5 compares all of them except F alone.
METHODS: tuple[str, ...] = ("raw", "calibrated", *BASELINE_NAMES, F_ALONE, PROPOSED)
PAPER_METHODS: tuple[str, ...] = tuple(m for m in METHODS if m != F_ALONE)
TABLE_THRESHOLDS_MM: tuple[float, ...] = (2.0, 5.0, 10.0)
RANK_THRESHOLD_MM = 5.0
SMOOTHING_BASELINES = ("JBF", "WMF", "RF-WF", "TV", "PD")
_EDGE_EXEMPT = frozenset({"n_trees"})

# The paper's numbers (§V-C, Fig. 5): fraction of pixels within 5 mm, whole image.
PAPER_WITHIN_5MM = {"raw": 0.30, "calibrated": 0.45, PROPOSED: 0.63}
PAPER_RANKING_NOTE = ("proposed 1st, RFD 2nd; TV, PD, RF-WF, WMF and JBF improve marginally on "
                      "the calibrated range; calibrated (45 %) above raw (30 %) at 5 mm")


# ----------------------------------------------------------------------------------------------
# Grids


@dataclass(frozen=True)
class GridSpec:
    """How one baseline is set up and searched.

    Attributes:
        init: constructor arguments held fixed (e.g. forest size).
        grid: name -> values searched; constructor ("fit") parameters and keywords of ``apply``
            may be mixed — a fit parameter means one fit per value.
    """

    init: dict[str, Any] = field(default_factory=dict)
    grid: dict[str, list[Any]] = field(default_factory=dict)


def default_grids(model: CorrectionModel, *, quick: bool = False) -> dict[str, GridSpec]:
    """The grids of every baseline.

    ``quick=False``: each baseline's own ``param_grid`` plus ``fit_param_grid`` with its default
    constructor (the full search; RFD alone refits a 30-tree forest per ``max_depth``, minutes).
    ``quick=True``: a few values around the full grids' usual winners and smaller forests and
    dictionary, for the demo (about a minute of tuning on the small simulated dataset).
    RFD always uses the model's patch encoding (the same features as F).
    """
    enc = {"encoding": model.encoding}
    if not quick:
        return {name: GridSpec(init=dict(enc) if name == "RFD" else {},
                               grid={**BASELINES[name].param_grid,
                                     **BASELINES[name].fit_param_grid})
                for name in BASELINE_NAMES}
    return {
        "JBF": GridSpec(grid={"sigma_space": [1.0, 2.0, 3.0], "sigma_color": [0.05, 0.1, 0.2]}),
        "WMF": GridSpec(grid={"radius": [1, 2, 3], "sigma": [10.0, 25.5, 50.0]}),
        "RF-WF": GridSpec(init={"n_estimators": 10, "max_samples": 30_000},
                          grid={"sigma": [1.0, 1.5, 2.0], "power": [1.0, 2.0]}),
        "RFD": GridSpec(init={**enc, "n_estimators": 10, "max_samples": 20_000},
                        grid={"n_trees": [5, 0]}),
        "TV": GridSpec(grid={"lam": [0.05, 0.2, 0.5], "data": ["l1", "l2"],
                             "amplitude_power": [1.0]}),
        "PD": GridSpec(init={"n_atoms": 128}, grid={"n_candidates": [4],
                                                    "smoothness": [0.5, 2.0]}),
    }


@dataclass
class BenchmarkConfig:
    """Settings of :func:`run_benchmark`.

    Attributes:
        grids: per baseline :class:`GridSpec`; None = :func:`default_grids` (``quick`` picks
            which); a subset of names benchmarks only those baselines.
        quick: small grids (the demo's).
        val_fraction: share of the training frames held out for the grid search.
        max_val_frames: cap on validation frames (evenly spaced); None = all.
        session_gap_s: stamp gap that separates capture sessions (scenes) for the split.
        n_examples: test frames shown in the qualitative panels and range profiles (2-3).
        thresholds: accuracy-curve thresholds in mm (must include 2, 5 and 10).
        profile_length_px: length of the range-profile line.
        progress: tqdm bars on stderr.
    """

    grids: dict[str, GridSpec] | None = None
    quick: bool = False
    val_fraction: float = 0.25
    max_val_frames: int | None = None
    session_gap_s: float = 300.0
    n_examples: int = 3
    thresholds: tuple[float, ...] = DEFAULT_THRESHOLDS_MM
    profile_length_px: int = DEFAULT_LENGTH_PX
    progress: bool = True

    def __post_init__(self) -> None:
        if not 0.0 < self.val_fraction < 1.0:
            raise InputError(f"val_fraction must be in (0, 1), got {self.val_fraction}")
        if self.max_val_frames is not None and self.max_val_frames < 1:
            raise InputError(f"max_val_frames must be >= 1, got {self.max_val_frames}")
        if self.n_examples < 0:
            raise InputError(f"n_examples must be >= 0, got {self.n_examples}")
        missing = [t for t in (*TABLE_THRESHOLDS_MM, RANK_THRESHOLD_MM)
                   if float(t) not in {float(x) for x in self.thresholds}]
        if missing:
            raise InputError(f"thresholds must include {missing} mm")
        if self.grids is not None:
            unknown = sorted(set(self.grids) - set(BASELINES))
            if unknown:
                raise InputError(f"unknown baselines {unknown}; known: {sorted(BASELINES)}")


# ----------------------------------------------------------------------------------------------
# Frames and the train/validation split


@dataclass
class CalibratedFrame:
    """What a baseline sees: the calibrated range, amplitude and the reference.

    Attributes:
        range_mm: (H, W) float32 calibrated radial range in mm, NaN = invalid.
        amplitude: (H, W) float32 amplitude.
        reference_mm: (H, W) float32 reference in mm, NaN = missing; or None.
    """

    range_mm: np.ndarray
    amplitude: np.ndarray
    reference_mm: np.ndarray | None


def calibrate_frames(model: CorrectionModel, frames: Iterable[ToFFrame]) -> list[CalibratedFrame]:
    """Apply the model's intrinsic calibration to every frame.

    Raises:
        InputError: a frame is not the model's crop.
    """
    out = []
    for frame in frames:
        r, a = check_frame_pair(model.shape, frame.range_mm, frame.amplitude)
        out.append(CalibratedFrame(model.calibration.apply(r, a), a.astype(np.float32),
                                   frame.reference_mm))
    return out


@dataclass(frozen=True)
class TrainValSplit:
    """Indices into the training frames.

    Attributes:
        fit: frames the learned baselines are fitted on.
        val: frames the grids are searched on.
        n_groups: capture sessions found (1 = none could be told apart).
        how: ``"sessions"`` (whole sessions held out) or ``"tail"`` (the last frames).
    """

    fit: tuple[int, ...]
    val: tuple[int, ...]
    n_groups: int
    how: str

    def to_dict(self) -> dict:
        return {"fit_frames": list(self.fit), "val_frames": list(self.val),
                "n_sessions": self.n_groups, "how": self.how}


def session_groups(stamps_ns: Sequence[int], sources: Sequence[int] | None = None, *,
                   gap_s: float = 300.0) -> list[int]:
    """Session id per frame: a new session starts at a new source (recording) or where the stamp
    jumps by more than ``gap_s`` seconds (either direction) from the previous frame's."""
    groups, current = [], 0
    for i, stamp in enumerate(stamps_ns):
        if i > 0 and (abs(int(stamp) - int(stamps_ns[i - 1])) > gap_s * 1e9
                      or (sources is not None and sources[i] != sources[i - 1])):
            current += 1
        groups.append(current)
    return groups


def split_train_val(stamps_ns: Sequence[int], val_fraction: float = 0.25, *,
                    sources: Sequence[int] | None = None, gap_s: float = 300.0,
                    max_val_frames: int | None = None) -> TrainValSplit:
    """Hold out about ``val_fraction`` of the training frames for the grid search.

    With several sessions, whole sessions are held out, taken evenly across the sequence (at
    least one, never all). With one session, the last ``ceil(val_fraction * N)`` frames. At most
    ``max_val_frames`` validation frames are kept (evenly spaced); the others are not used.

    Args:
        stamps_ns: (N,) capture stamps in ns, in frame order.
        val_fraction: target share of frames in validation.
        sources: (N,) recording index per frame (a new recording starts a session).
        gap_s: session gap in seconds.
        max_val_frames: cap on validation frames.

    Raises:
        InputError: fewer than 2 frames.
    """
    n = len(stamps_ns)
    if n < 2:
        raise InputError(f"the benchmark needs at least 2 training frames (fit + validation), "
                         f"got {n}")
    groups = np.asarray(session_groups(stamps_ns, sources, gap_s=gap_s))
    n_groups = int(groups.max()) + 1
    if n_groups >= 2:
        n_val_groups = int(np.clip(round(val_fraction * n_groups), 1, n_groups - 1))
        # Evenly spaced sessions, the last one always included.
        chosen = [(i + 1) * n_groups // n_val_groups - 1 for i in range(n_val_groups)]
        is_val = np.isin(groups, chosen)
        how = "sessions"
    else:
        n_val = int(np.clip(np.ceil(val_fraction * n), 1, n - 1))
        is_val = np.arange(n) >= n - n_val
        how = "tail"
    val = np.flatnonzero(is_val)
    if max_val_frames is not None and val.size > max_val_frames:
        val = val[np.round(np.linspace(0, val.size - 1, max_val_frames)).astype(int)]
    return TrainValSplit(tuple(np.flatnonzero(~is_val).tolist()), tuple(val.tolist()),
                         n_groups, how)


# ----------------------------------------------------------------------------------------------
# Baseline tuning


def _jsonable(value: Any) -> Any:
    """JSON-friendly form of a parameter value (numpy scalars, dataclasses such as F's
    encoding constants)."""
    if isinstance(value, np.generic):
        return value.item()
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {k: _jsonable(v) for k, v in dataclasses.asdict(value).items()}
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


@dataclass
class TunedBaseline:
    """A baseline fitted and grid-searched, ready for the test frames.

    Attributes:
        name: registry name.
        method: the fitted instance with the chosen fit parameters.
        apply_params: the chosen keywords of ``apply``.
        chosen: every chosen value (fit and apply parameters).
        spec: the :class:`GridSpec` searched.
        table: one row per combination: ``{"params", "score", "n_pixels",
            "seconds_per_frame"}`` (score = fraction within 5 mm on the validation frames).
        val_score: the chosen combination's score.
        fit_seconds: total fitting time (all fit-parameter values).
        search_seconds: total tuning time, fits included.
        n_fit_frames, n_val_frames: frames used.
    """

    name: str
    method: Baseline
    apply_params: dict[str, Any]
    chosen: dict[str, Any]
    spec: GridSpec
    table: list[dict[str, Any]]
    val_score: float
    fit_seconds: float
    search_seconds: float
    n_fit_frames: int
    n_val_frames: int

    def at_grid_edge(self) -> list[str]:
        """Numeric parameters whose chosen value is the smallest or largest of 3+ searched
        values: a wider grid might score higher. ``n_trees`` is exempt (0 = all trees, the top
        of its range by construction)."""
        out = []
        for key, values in self.spec.grid.items():
            numeric = [v for v in values if isinstance(v, (int, float)) and
                       not isinstance(v, bool)]
            if key in _EDGE_EXEMPT or len(numeric) < 3 or len(numeric) != len(values):
                continue
            if self.chosen.get(key) in (min(numeric), max(numeric)):
                out.append(key)
        return out

    def n_training_pixels(self) -> int | None:
        """Pixels a learned baseline was fitted on (upper bound), None when not learned."""
        fp = self.method.fit_params
        if "samples_per_frame" not in fp:
            return None
        return per_frame_quota(fp, self.n_fit_frames) * self.n_fit_frames

    def to_dict(self) -> dict:
        return {"init": _jsonable(self.spec.init), "grid_searched": _jsonable(self.spec.grid),
                "chosen": _jsonable(self.chosen), "val_score_within_5mm": self.val_score,
                "n_combinations": len(self.table), "table": self.table,
                "fit_seconds": self.fit_seconds, "search_seconds": self.search_seconds,
                "n_fit_frames": self.n_fit_frames, "n_val_frames": self.n_val_frames,
                "n_training_pixels": self.n_training_pixels(),
                "chosen_at_grid_edge": self.at_grid_edge(),
                "learned": bool(self.method.supervised)}


def tune_baseline(name: str, spec: GridSpec, fit_frames: Sequence[CalibratedFrame],
                  val_frames: Sequence[CalibratedFrame]) -> TunedBaseline:
    """Fit (once per fit-parameter combination) and grid-search one baseline.

    Args:
        name: a key of :data:`~tof_mpd_ros.evaluation.baselines.BASELINES`.
        spec: constructor arguments and the grid.
        fit_frames: calibrated frames with references to fit learned methods on.
        val_frames: calibrated frames with references to score combinations on.

    Returns:
        The :class:`TunedBaseline` holding the best fitted instance; ties go to the first
        combination in grid order.

    Raises:
        InputError: unknown baseline or parameter names, empty grids, no validation pixels.
    """
    if name not in BASELINES:
        raise InputError(f"unknown baseline {name!r}; known: {sorted(BASELINES)}")
    cls = BASELINES[name]
    start = time.perf_counter()
    probe = cls(**spec.init)
    apply_names = set(cls.apply_param_names())
    fit_grid = {k: v for k, v in spec.grid.items() if k not in apply_names}
    apply_grid = {k: v for k, v in spec.grid.items() if k in apply_names}
    unknown = sorted(k for k in fit_grid if k not in probe.fit_params)
    if unknown:
        raise InputError(f"{name} has no parameter {unknown}; apply parameters: "
                         f"{sorted(apply_names)}, fit parameters: {sorted(probe.fit_params)}")
    for key, values in fit_grid.items():
        if not isinstance(values, (list, tuple)) or len(values) == 0:
            raise InputError(f"grid for {key!r} must be a non-empty list, got {values!r}")
    table: list[dict[str, Any]] = []
    best: tuple[float, Baseline, dict[str, Any], dict[str, Any]] | None = None
    fit_seconds = 0.0
    for values in itertools.product(*fit_grid.values()):
        fit_combo = dict(zip(fit_grid, values, strict=True))
        method = cls(**{**spec.init, **fit_combo}) if fit_combo else probe
        t0 = time.perf_counter()
        method.fit(fit_frames)
        fit_seconds += time.perf_counter() - t0
        params, rows = grid_search(method, val_frames, apply_grid)
        for row in rows:
            row["params"] = {**{k: _jsonable(v) for k, v in fit_combo.items()}, **row["params"]}
        table.extend(rows)
        score = max(row["score"] for row in rows)
        if best is None or score > best[0]:
            best = (score, method, params, fit_combo)
    assert best is not None  # itertools.product of an empty grid yields one empty combination
    score, method, params, fit_combo = best
    return TunedBaseline(name, method, params, _jsonable({**fit_combo, **params}), spec, table,
                         score, fit_seconds, time.perf_counter() - start, len(fit_frames),
                         len(val_frames))


# ----------------------------------------------------------------------------------------------
# Ranking and the comparison with the paper


def rank_methods(whole: Mapping[str, float], boundary: Mapping[str, float],
                 mae: Mapping[str, float] | None = None) -> list[str]:
    """Methods best first: by accuracy on the whole image, then boundary accuracy, then lower
    MAE, then name (deterministic). NaN accuracies rank last."""
    def key(name: str) -> tuple:
        w, b = whole[name], boundary.get(name, float("nan"))
        m = float("inf") if mae is None else mae.get(name, float("inf"))
        return (-(w if np.isfinite(w) else -1.0), -(b if np.isfinite(b) else -1.0),
                m if np.isfinite(m) else float("inf"), name)

    return sorted(whole, key=key)


def _pct(x: float) -> str:
    return f"{100.0 * x:.1f} %"


def _ordinal(n: int) -> str:
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


_EDGE_REGION, _INTERIOR_REGION = "edge (<= 2 px)", "interior (> 5 px)"


def _miss_text(names: Sequence[str], evidence: Mapping[str, Any]) -> str:
    """What the misses (≥ 5 mm) of ``names`` are made of, as measured, and which lever that
    points to; empty without the measurement."""
    tally = evidence.get("misses")
    if not tally:
        return ""
    per = {n: tally["methods"][n] for n in names if n in tally["methods"]}
    if not per:
        return ""
    clip = tally.get("clip_mm")
    parts = []
    for n, m in per.items():
        noisy = m.get("noise_limited")
        beyond = m.get("beyond_clip")
        parts.append(f"{n} {_pct(m['miss_share'])} missed"
                     + (f", {_pct(noisy)} of them noise-limited" if noisy is not None else "")
                     + (f", {_pct(beyond)} beyond ±{clip:.0f} mm" if beyond is not None
                        else ""))
    text = (" Measured on these frames (noise-limited: the 5×5 local mean error is within "
            f"5 mm; beyond ±{clip:.0f} mm: |reference − calibrated| exceeds F's target "
            "truncation, out of F's reach by construction): " + "; ".join(parts) + ".")
    own = per.get(PROPOSED) or per.get(F_ALONE)
    if own is None:
        return text
    noisy, beyond = own.get("noise_limited") or 0.0, own.get("beyond_clip") or 0.0
    if beyond >= 0.5:
        text += (f" Most of the proposed method's misses lie beyond F's ±{clip:.0f} mm "
                 "truncation, out of its reach by construction (a wider truncation reaches "
                 "them at a cost elsewhere: tof-mpd train chooses it on validation frames, "
                 "--target-clip-mm).")
    elif noisy >= 0.5:
        text += (" Most of the proposed method's misses are noise-limited: the local mean is "
                 "within 5 mm, the pixel's own noise is not.")
    else:
        text += (" Most of the proposed method's misses are bias within F's reach (neither "
                 "noise-limited nor beyond the truncation): distortion F did not learn.")
    return text


def _region_text(names: Sequence[str], evidence: Mapping[str, Any]) -> str:
    """Accuracy within 2 px of an edge and beyond 5 px for ``names``; empty if not measured."""
    regions = evidence.get("regions")
    if not regions:
        return ""
    edge, inner = regions.get(_EDGE_REGION, {}), regions.get(_INTERIOR_REGION, {})
    parts = [f"{n} {_pct(edge[n]['within'])} / {_pct(inner[n]['within'])}"
             for n in names if n in edge and n in inner]
    return (" Within 5 mm on pixels ≤ 2 px from an edge / > 5 px from any: "
            + ", ".join(parts) + ".") if parts else ""


def _edge_loss(name: str, evidence: Mapping[str, Any]) -> str:
    """Where ``name`` loses against calibrated: on the edge or in the interior (measured)."""
    regions = evidence.get("regions")
    if not regions:
        return ""
    edge, inner = regions.get(_EDGE_REGION, {}), regions.get(_INTERIOR_REGION, {})
    if name not in edge or "calibrated" not in edge:
        return ""
    d_edge = edge[name]["within"] - edge["calibrated"]["within"]
    d_inner = inner[name]["within"] - inner["calibrated"]["within"]
    where = ("it loses on the edges themselves (smoothing across the discontinuities)"
             if d_edge < d_inner else "it loses as much away from the edges")
    return (f"; against calibrated it moves {100 * d_edge:+.1f} points within 2 px of an edge "
            f"and {100 * d_inner:+.1f} points beyond 5 px: {where}")


def _geodesic_ablation(f_acc: tuple[float, float], full_acc: tuple[float, float],
                       evidence: Mapping[str, Any]) -> str | None:
    """Why the geodesic step with G did not add to F, from the reference-edge ablation."""
    oracle = evidence.get("reference_edges")
    if oracle is None:
        return None
    text = (f"Ablation: with the reference's edges in place of G's, the full method scores "
            f"{_pct(oracle[0])} / {_pct(oracle[1])} (F alone {_pct(f_acc[0])} / "
            f"{_pct(f_acc[1])}, with G {_pct(full_acc[0])} / {_pct(full_acc[1])}). ")
    if oracle[1] >= f_acc[1] and oracle[0] >= f_acc[0]:
        text += ("With true edges the geodesic step helps, so G's edge map is what costs "
                 "accuracy here.")
    else:
        text += ("Even with true edges the geodesic step does not help: the filter itself "
                 "(averaging R_F over 81 neighbours) costs accuracy on these frames, not G.")
    return text + _region_text([F_ALONE, PROPOSED, REFERENCE_EDGES], evidence)


def compare_with_paper(acc5: Mapping[str, tuple[float, float]], evidence: Mapping[str, Any]
                       ) -> dict[str, Any]:
    """The ranking at 5 mm and every way it differs from the paper's, with the reason.

    Args:
        acc5: method -> (fraction within 5 mm whole image, boundary region), for the methods of
            the paper's Fig. 5 (raw, calibrated, the baselines present, ``proposed``); may also
            hold ``F`` (ranked separately, it is a component).
        evidence: measurements explaining differences (any may be absent):
            ``noise_share`` (fraction of the calibrated error variance away from boundaries
            that is pixel-to-pixel noise), ``noise_rms_mm``, ``bias_rms_mm``,
            ``boundary_share`` (fraction of evaluated pixels in the boundary region),
            ``val_scores`` (method -> validation score at 5 mm), ``val_calibrated`` (calibrated
            on the same validation frames), ``rfd_training_pixels``, ``rfd_chosen`` (its chosen
            parameters), ``f_training_patches``, ``f_epochs``.

    Returns:
        ``{"ranking_whole": [...], "ranking_boundary": [...], "statement": str,
        "findings": [{"aspect", "paper", "ours", "agrees", "why"}...], "targets": {...}}``.
    """
    paper = {k: v for k, v in acc5.items() if k != F_ALONE}
    if PROPOSED not in paper or "calibrated" not in paper or "raw" not in paper:
        raise InputError("compare_with_paper needs raw, calibrated and proposed")
    whole = {k: v[0] for k, v in paper.items()}
    bound = {k: v[1] for k, v in paper.items()}
    rank_w = rank_methods(whole, bound)
    rank_b = rank_methods(bound, whole)
    baselines = [m for m in BASELINE_NAMES if m in paper]
    findings: list[dict[str, Any]] = []
    noise = evidence.get("noise_share")
    noise_txt = ""
    if noise is not None:
        noise_txt = (f"Away from boundaries {_pct(noise)} of the calibrated error variance is "
                     f"pixel-to-pixel noise (rms {evidence.get('noise_rms_mm', float('nan')):.1f}"
                     f" mm) and the rest a spatially smooth bias (rms "
                     f"{evidence.get('bias_rms_mm', float('nan')):.1f} mm, mostly multipath).")

    def f_training() -> str:
        patches, epochs = evidence.get("f_training_patches"), evidence.get("f_epochs")
        if patches is None:
            return ""
        return (f" F and G were trained on {patches:,} patches"
                + (f" for {epochs} epochs" if epochs is not None else "")
                + " (the paper: ~10 M patches, 40 epochs).")

    # 1. Who is first (whole image and boundary region).
    for region, ranking, scores in (("whole image", rank_w, whole),
                                    ("boundary region", rank_b, bound)):
        top = ranking[0]
        agrees = top == PROPOSED
        why = None
        if not agrees:
            margin = scores[top] - scores[PROPOSED]
            why = (f"{top} is {100 * margin:.1f} points above the proposed method.")
            if top == "RFD":
                why += _miss_text([PROPOSED, F_ALONE, "RFD"], evidence) + f_training()
            elif top in SMOOTHING_BASELINES:
                why += (" " + noise_txt + _miss_text([PROPOSED, top], evidence))
            elif top == "calibrated":
                why += (_region_text(["calibrated", F_ALONE, PROPOSED], evidence)
                        + _miss_text([PROPOSED, F_ALONE], evidence) + f_training())
        findings.append({"aspect": f"best method at 5 mm, {region}", "paper": PROPOSED,
                         "ours": top, "agrees": agrees, "why": why})

    val, val_cal = evidence.get("val_scores", {}), evidence.get("val_calibrated")

    # 2. RFD second (the paper's ranking), in each region.
    for region, ranking, scores in (("whole image", rank_w, whole),
                                    ("boundary region", rank_b, bound)):
        if "RFD" not in paper:
            break
        second = ranking[1]
        agrees = second == "RFD"
        why = None
        if not agrees:
            rfd_pos = ranking.index("RFD") + 1
            ahead = [m for m in ranking[:rfd_pos - 1] if m != PROPOSED]
            if not ahead:
                parts = [f"RFD ranks {_ordinal(rfd_pos)}, above the proposed method (see the "
                         f"best-method finding); {second} follows it."]
            else:
                parts = [f"RFD is {_ordinal(rfd_pos)} ({_pct(scores['RFD'])} within 5 mm); "
                         f"{', '.join(ahead)} {'rank' if len(ahead) > 1 else 'ranks'} "
                         "above it."]
            smoothers = [m for m in ahead if m in SMOOTHING_BASELINES]
            if smoothers:
                parts.append(noise_txt + _miss_text(["RFD", *smoothers], evidence))
            if "calibrated" in ahead:
                parts.append("RFD falls below the calibrated range on these frames, though "
                             "it was chosen on validation frames"
                             + (f" where it scored {_pct(val['RFD'])} (calibrated "
                                f"{_pct(val_cal)})" if "RFD" in val and val_cal is not None
                                else "") + "."
                             + _region_text(["calibrated", "RFD"], evidence))
            pixels = evidence.get("rfd_training_pixels")
            if pixels is not None:
                parts.append(f"RFD was fitted on {pixels:,} sampled pixels of the fit split "
                             "(the paper trained it on the same ~10 M patches as F).")
            why = " ".join(parts)
        findings.append({"aspect": f"second at 5 mm, {region}", "paper": "RFD",
                         "ours": second, "agrees": agrees, "why": why})

    # 3. Every baseline above calibrated (marginally for all but RFD), in each region.
    for region, scores in (("whole image", whole), ("boundary region", bound)):
        below = [m for m in baselines if scores[m] < scores["calibrated"]]
        why = None
        if below:
            reasons = []
            for m in below:
                if region == "boundary region":
                    reasons.append(
                        f"{m}: {_pct(scores[m])} vs calibrated {_pct(scores['calibrated'])} "
                        f"near boundaries ({_pct(whole[m])} vs {_pct(whole['calibrated'])} on "
                        "the whole image)" + _edge_loss(m, evidence))
                elif m in val and val_cal is not None and val[m] <= val_cal:
                    reasons.append(f"{m}: no setting of its grid beat calibration even on the "
                                   f"validation frames ({_pct(val[m])} vs {_pct(val_cal)}); "
                                   "its smoothing costs more at boundaries than it removes")
                elif m in val and val_cal is not None:
                    reasons.append(f"{m}: above calibration on the validation frames "
                                   f"({_pct(val[m])} vs {_pct(val_cal)}) but not on the test "
                                   "frames: the chosen parameters do not transfer to the test "
                                   "objects")
                else:
                    reasons.append(f"{m}: below calibration")
            share = evidence.get("boundary_share")
            why = "; ".join(reasons) + "." + (
                f" {_pct(share)} of the evaluated pixels are within 5 px of a boundary."
                if share is not None else "")
        findings.append({"aspect": f"every baseline improves on the calibrated range, {region}",
                         "paper": "yes (marginally, RFD clearly)",
                         "ours": "yes" if not below else
                         f"no: {', '.join(below)} below calibrated",
                         "agrees": not below, "why": why})

    # 4. Calibration helps.
    agrees = whole["calibrated"] > whole["raw"]
    findings.append({
        "aspect": "calibrated vs raw at 5 mm",
        "paper": f"{_pct(PAPER_WITHIN_5MM['raw'])} -> {_pct(PAPER_WITHIN_5MM['calibrated'])}",
        "ours": f"{_pct(whole['raw'])} -> {_pct(whole['calibrated'])}", "agrees": agrees,
        "why": None if agrees else "the per-pixel linear calibration did not improve the "
                                   "test frames: its fit (checkerboard captures) does not "
                                   "describe this camera's systematic error"})

    # 5. F alone vs the full method (component analysis, Fig. 8).
    if F_ALONE in acc5:
        f_w, f_b = acc5[F_ALONE]
        agrees = whole[PROPOSED] >= f_w and bound[PROPOSED] >= f_b
        findings.append({
            "aspect": "geodesic filtering with G adds to F (component analysis)",
            "paper": "yes, mostly in the boundary region",
            "ours": (f"F {_pct(f_w)} / {_pct(f_b)} -> full {_pct(whole[PROPOSED])} / "
                     f"{_pct(bound[PROPOSED])} (whole / boundary)"),
            "agrees": agrees,
            "why": None if agrees else _geodesic_ablation(
                (f_w, f_b), (whole[PROPOSED], bound[PROPOSED]), evidence)})

    # 6. The network F against the forest RFD on the same features and target (the paper's
    # argument for a network: "Comparison with the RFD justified the use of NNs").
    if F_ALONE in acc5 and "RFD" in paper:
        f_w, f_b = acc5[F_ALONE]
        agrees = f_w >= whole["RFD"] and f_b >= bound["RFD"]
        why = None
        if not agrees:
            chosen = evidence.get("rfd_chosen")
            pixels = evidence.get("rfd_training_pixels")
            why = ("RFD's forest matches or beats F alone here"
                   + (f" (grid-searched, chose {chosen}" if chosen else "")
                   + (f", fitted on {pixels:,} pixels)" if chosen and pixels is not None
                      else ")" if chosen else "") + "." + f_training()
                   + _miss_text([F_ALONE, "RFD"], evidence))
        findings.append({
            "aspect": "F alone (network) vs RFD (forest) on the same features",
            "paper": "F better (the paper's argument for a network)",
            "ours": (f"F {_pct(f_w)} / {_pct(f_b)} vs RFD {_pct(whole['RFD'])} / "
                     f"{_pct(bound['RFD'])} (whole / boundary)"),
            "agrees": agrees, "why": why})

    targets = {f"proposed_beats_every_baseline_{region}": all(scores[PROPOSED] > scores[m]
                                                              for m in baselines)
               for region, scores in (("whole", whole), ("boundary", bound))}
    order = " > ".join(f"{m} ({_pct(whole[m])})" for m in rank_w)
    statement = (f"Ranking at 5 mm, whole image: {order}. Boundary region: "
                 + " > ".join(f"{m} ({_pct(bound[m])})" for m in rank_b) + ".")
    return {"ranking_whole": rank_w, "ranking_boundary": rank_b, "statement": statement,
            "paper_ranking": PAPER_RANKING_NOTE, "paper_within_5mm": PAPER_WITHIN_5MM,
            "findings": findings, "targets": targets}


# ----------------------------------------------------------------------------------------------
# Error decomposition (evidence for the ranking)


@dataclass
class NoiseTally:
    """Splits the calibrated error away from boundaries into pixel noise and smooth bias.

    Per frame, ``e = calibrated - reference`` on valid non-boundary pixels; the smooth part is
    e's normalised box mean over ``size`` x ``size`` valid non-boundary neighbours; the noise
    part is the residual. Sums of squares are pooled over frames.
    """

    size: int = 5
    noise_sq: float = 0.0
    bias_sq: float = 0.0
    n: int = 0

    def add(self, calibrated: np.ndarray, reference: np.ndarray, boundary: np.ndarray) -> None:
        """Pool one frame: (H, W) calibrated and reference range in mm, (H, W) bool region."""
        e = calibrated.astype(np.float64) - reference
        m = np.isfinite(e) & ~boundary
        if not m.any():
            return
        smooth = local_mean(e, m, self.size)[m]
        self.noise_sq += float(np.square(e[m] - smooth).sum())
        self.bias_sq += float(np.square(smooth).sum())
        self.n += int(m.sum())

    def to_dict(self) -> dict:
        total = self.noise_sq + self.bias_sq
        return {"noise_share": self.noise_sq / total if total > 0 else None,
                "noise_rms_mm": float(np.sqrt(self.noise_sq / self.n)) if self.n else None,
                "bias_rms_mm": float(np.sqrt(self.bias_sq / self.n)) if self.n else None,
                "n_pixels": self.n, "box_px": self.size}


# ----------------------------------------------------------------------------------------------
# The benchmark


@dataclass
class BenchmarkResult:
    """Everything the benchmark measured.

    Attributes:
        methods: method -> pooled accuracy curves (whole, boundary) on the test frames.
        seconds_per_frame: method -> median wall time per frame (s), calibration included.
        tuned: baseline name -> :class:`TunedBaseline`.
        components: the component analysis and G-vs-Canny edge curves on the same frames.
        split: the train/validation split.
        comparison: :func:`compare_with_paper` output.
        diagnostics: error decomposition and context numbers.
        examples: per example frame: ``index``, ``reference``, ``amplitude``, ``estimates``
            (method -> (H, W) mm), ``edges_g``, ``line`` (:class:`ProfileLine` or None),
            ``profiles`` (method -> (L,) mm, ``reference`` included).
        n_frames: test frames evaluated; n_skipped: test frames without a reference.
        timings: stage -> seconds of the benchmark run itself.
        info: provenance (machine, config).
    """

    methods: dict[str, FrameEvaluation]
    seconds_per_frame: dict[str, float]
    tuned: dict[str, TunedBaseline]
    components: ComponentEvaluation
    split: TrainValSplit
    comparison: dict[str, Any]
    diagnostics: dict[str, Any]
    examples: list[dict[str, Any]]
    n_frames: int
    n_skipped: int
    timings: dict[str, float]
    info: dict[str, Any]

    def table(self, thresholds: Sequence[float] = TABLE_THRESHOLDS_MM) -> dict[str, dict]:
        """Per method: fraction within each threshold (whole, boundary), MAE (whole,
        boundary) in mm and ms per frame."""
        out = {}
        for name, ev in self.methods.items():
            row: dict[str, Any] = {}
            for t in thresholds:
                row[f"whole_{t:g}mm"] = ev.whole.at(t)
                row[f"boundary_{t:g}mm"] = ev.boundary.at(t)
            row.update(mae_mm=ev.whole.mae_mm, boundary_mae_mm=ev.boundary.mae_mm,
                       rmse_mm=ev.whole.rmse_mm, ms_per_frame=1e3 * self.seconds_per_frame[name])
            out[name] = row
        return out

    def best_baselines(self, n: int = 2, region: str = "boundary") -> list[str]:
        """The ``n`` baselines with the highest accuracy at 5 mm in ``region``."""
        names = [m for m in BASELINE_NAMES if m in self.methods]
        return sorted(names, key=lambda m: -getattr(self.methods[m], region).at(5.0))[:n]

    def to_dict(self) -> dict:
        def finite(x: float) -> float | None:
            return float(x) if np.isfinite(x) else None

        return {
            "n_test_frames": self.n_frames, "n_test_frames_without_reference": self.n_skipped,
            "methods_order": [m for m in METHODS if m in self.methods],
            "table": {m: {k: finite(v) for k, v in row.items()}
                      for m, row in self.table().items()},
            "comparison": self.comparison,
            "methods": {m: {**ev.to_dict(), "seconds_per_frame": self.seconds_per_frame[m]}
                        for m, ev in self.methods.items()},
            "baselines": {m: t.to_dict() for m, t in self.tuned.items()},
            "split": self.split.to_dict(),
            "components": self.components.to_dict(),
            "diagnostics": self.diagnostics,
            "examples": [{"test_frame": ex["index"],
                          "profile_line": None if ex["line"] is None else ex["line"].to_dict(),
                          "profiles_mm": {k: [finite(x) for x in v]
                                          for k, v in ex["profiles"].items()}}
                         for ex in self.examples],
            "timings_s": self.timings, "info": self.info,
        }


def machine_info() -> dict[str, Any]:
    """The machine the run was on (for the absolute timings)."""
    import os

    from ..machine import cpu_model

    return {"cpu": cpu_model(), "cpu_count": os.cpu_count(),
            "torch_threads": torch.get_num_threads(),
            "python": platform.python_version(), "platform": platform.platform()}


def _bar(total: int, desc: str, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, disable=not enabled, file=sys.stderr, leave=True)


def run_benchmark(model: CorrectionModel, train_frames: Iterable[ToFFrame],
                  test_frames: Iterable[ToFFrame], config: BenchmarkConfig | None = None, *,
                  train_sources: Sequence[int] | None = None,
                  on_stage: Callable[[str], None] | None = None) -> BenchmarkResult:
    """Run every method on the same test frames (see the module doc for the protocol).

    Args:
        model: the correction model (calibration, F, G); frames must be its crop.
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
    timings: dict[str, float] = {}
    start = time.perf_counter()
    grids = cfg.grids if cfg.grids is not None else default_grids(model, quick=cfg.quick)

    # 1. Calibrate the training frames and split them.
    say("calibrating the training frames")
    train = list(train_frames)
    sources = list(train_sources) if train_sources is not None else None
    keep = [i for i, f in enumerate(train) if f.reference_mm is not None]
    train_cal = calibrate_frames(model, (train[i] for i in keep))
    split = split_train_val([train[i].stamp_ns for i in keep], cfg.val_fraction,
                            sources=None if sources is None else [sources[i] for i in keep],
                            gap_s=cfg.session_gap_s, max_val_frames=cfg.max_val_frames)
    split = TrainValSplit(tuple(keep[i] for i in split.fit), tuple(keep[i] for i in split.val),
                          split.n_groups, split.how)
    by_index = dict(zip(keep, train_cal, strict=True))
    fit_frames = [by_index[i] for i in split.fit]
    val_frames = [by_index[i] for i in split.val]
    del train
    timings["calibrate_train_s"] = time.perf_counter() - start

    # 2. Fit and grid-search the baselines.
    tuned: dict[str, TunedBaseline] = {}
    names = [n for n in BASELINE_NAMES if n in grids]
    say(f"fitting and grid-searching {len(names)} baselines on {len(fit_frames)} fit / "
        f"{len(val_frames)} validation frames")
    t0 = time.perf_counter()
    with _bar(len(names), "tuning baselines", cfg.progress) as bar:
        for name in names:
            bar.set_postfix_str(name)
            tuned[name] = tune_baseline(name, grids[name], fit_frames, val_frames)
            log.debug("%s: chose %s (validation %.3f)", name, tuned[name].chosen,
                      tuned[name].val_score)
            bar.update(1)
    val_hits = [within_threshold(f.range_mm, f.reference_mm) for f in val_frames]
    val_calibrated = sum(h for h, _ in val_hits) / max(1.0, sum(c for _, c in val_hits))
    del fit_frames, val_frames, by_index, train_cal
    timings["tune_baselines_s"] = time.perf_counter() - t0

    # 3. The test frames.
    t0 = time.perf_counter()
    tests, skipped = [], 0
    for frame in test_frames:
        if frame.reference_mm is None:
            skipped += 1
        else:
            tests.append(frame)
    n_total = len(tests)
    if not tests:
        raise InputError("no test frame has a reference to evaluate against")
    methods = [m for m in METHODS if m not in BASELINE_NAMES or m in tuned]
    acc = {m: FrameAccumulator(cfg.thresholds) for m in methods}
    stage_acc = {s: FrameAccumulator(cfg.thresholds) for s in STAGES}
    seconds: dict[str, list[float]] = {m: [] for m in methods}
    g_scores, canny_scores, gts, valids = [], [], [], []
    noise = NoiseTally()
    n_ex = min(cfg.n_examples, n_total)
    # Evenly spread, distinct frames (different scenes in a multi-scene test set).
    example_idx = {(i + 1) * n_total // (n_ex + 1) for i in range(n_ex)} if n_total > n_ex \
        else set(range(n_total))
    examples: list[dict[str, Any]] = []
    n_boundary = n_eval = 0
    regions = RegionTally(RANK_THRESHOLD_MM)
    misses = MissTally(float(model.range_net.target_clip_mm), RANK_THRESHOLD_MM)
    ablation = FrameAccumulator(cfg.thresholds)
    say(f"running {len(methods)} methods on {n_total} test frames")
    with _bar(n_total, "benchmark test frames", cfg.progress) as bar:
        for index, frame in enumerate(tests):
            r, a = check_frame_pair(model.shape, frame.range_mm, frame.amplitude)
            ref = frame.reference_mm
            assert ref is not None
            tc = time.perf_counter()
            cal = model.calibration.apply(r, a)
            t_cal = time.perf_counter() - tc
            tc = time.perf_counter()
            full = correct(model, r, a)
            t_full = time.perf_counter() - tc
            tc = time.perf_counter()
            f_only = correct(model, r, a, use_boundary=False)
            t_f = time.perf_counter() - tc
            g_only = correct(model, r, a, use_range_net=False)
            est = {"raw": r.astype(np.float32), "calibrated": cal, F_ALONE: f_only.range_mm,
                   PROPOSED: full.range_mm}
            times = {"raw": 0.0, "calibrated": t_cal, F_ALONE: t_f, PROPOSED: t_full}
            for name, tb in tuned.items():
                tc = time.perf_counter()
                est[name] = tb.method.apply(cal, a, **tb.apply_params)
                times[name] = t_cal + time.perf_counter() - tc
            gt, _ = ground_truth_edges(ref)
            mask = boundary_region(ref, edges=gt)
            for m in methods:
                acc[m].add(est[m], ref, mask)
                seconds[m].append(times[m])
            oracle = _with_reference_edges(model, full.range_f_mm, gt, full.range_mm)
            ablation.add(oracle, ref, mask)
            regions.add({**est, REFERENCE_EDGES: oracle}, ref, edge_distance(gt))
            misses.add(est, ref, cal)
            stages = {"raw": r, "calibrated": full.calibrated_mm, "F": full.range_f_mm,
                      "geodesic+G": g_only.range_mm, "full": full.range_mm}
            for s in STAGES:
                stage_acc[s].add(stages[s], ref, mask)
            valid_ref = np.isfinite(ref)
            gts.append(gt)
            valids.append(valid_ref)
            g_scores.append(g_edge_strength(model, full.calibrated_mm, a))
            canny_scores.append(canny_score_map(r, highs=np.array(CANNY_HIGHS_MM)))
            noise.add(cal, ref, mask)
            n_eval += int(valid_ref.sum())
            n_boundary += int((valid_ref & mask).sum())
            if index in example_idx:
                examples.append(_example(index, ref, a, est, full.edges, gt,
                                         cfg.profile_length_px))
            bar.update(1)
    timings["test_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    evaluations = {m: acc[m].result() for m in methods}
    edges = {"G": edge_precision_recall(g_scores, gts, G_THRESHOLDS, valid=valids),
             "Canny (raw ToF)": edge_precision_recall(canny_scores, gts, CANNY_HIGHS_MM,
                                                      valid=valids)}
    components = ComponentEvaluation({s: stage_acc[s].result() for s in STAGES}, edges,
                                     float(np.median(seconds[PROPOSED])), n_total)
    medians = {m: float(np.median(v)) for m, v in seconds.items()}
    diagnostics = {"calibrated_error_away_from_boundaries": noise.to_dict(),
                   "boundary_share": n_boundary / n_eval if n_eval else None,
                   "val_calibrated_within_5mm": val_calibrated}
    oracle_eval = ablation.result()
    final = model.metadata.get("final", {}) if isinstance(model.metadata, dict) else {}
    train_cfg = model.metadata.get("train_config", {}) if isinstance(model.metadata,
                                                                     dict) else {}
    evidence = {**noise.to_dict(), "boundary_share": diagnostics["boundary_share"],
                "val_scores": {m: t.val_score for m, t in tuned.items()},
                "val_calibrated": val_calibrated,
                "rfd_training_pixels": tuned["RFD"].n_training_pixels() if "RFD" in tuned
                else None,
                "rfd_chosen": tuned["RFD"].chosen if "RFD" in tuned else None,
                "f_training_patches": final.get("patches"), "f_epochs": train_cfg.get("epochs"),
                "regions": regions.result(), "misses": misses.result(),
                "reference_edges": (oracle_eval.whole.at(RANK_THRESHOLD_MM),
                                    oracle_eval.boundary.at(RANK_THRESHOLD_MM))}
    diagnostics.update(regions_within_5mm=evidence["regions"], misses=evidence["misses"],
                       ablation_reference_edges=oracle_eval.to_dict())
    acc5 = {m: (ev.whole.at(RANK_THRESHOLD_MM), ev.boundary.at(RANK_THRESHOLD_MM))
            for m, ev in evaluations.items()}
    comparison = compare_with_paper(acc5, evidence)
    timings["metrics_s"] = time.perf_counter() - t0
    timings["total_s"] = time.perf_counter() - start
    info = {"machine": machine_info(), "quick": cfg.quick, "val_fraction": cfg.val_fraction,
            "max_val_frames": cfg.max_val_frames, "thresholds_mm": list(cfg.thresholds),
            "rank_threshold_mm": RANK_THRESHOLD_MM, "model_shape": list(model.shape),
            "timing_note": "median wall time per frame on this machine, calibration included "
                           "for every method after raw; the machine may be shared"}
    return BenchmarkResult(evaluations, medians, tuned, components, split, comparison,
                           diagnostics, examples, n_total, skipped, timings, info)


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


__all__ = [
    "BASELINE_NAMES", "METHODS", "PAPER_METHODS", "PROPOSED", "BenchmarkConfig",
    "BenchmarkResult", "CalibratedFrame", "GridSpec", "ProfileLine", "TrainValSplit",
    "TunedBaseline", "calibrate_frames", "compare_with_paper", "default_grids", "rank_methods",
    "run_benchmark", "session_groups", "split_train_val", "tune_baseline",
]
