"""The paper's evaluation (§V-B): accuracy-vs-threshold curves and edge precision / recall.

Definitions used everywhere here:

* **evaluated pixel**: reference range finite (missing reference pixels are neither used nor
  counted, as in the paper) and inside the optional mask;
* **accuracy at t**: fraction of evaluated pixels with ``|estimate - reference| < t`` (strict,
  "less than a threshold"). An evaluated pixel whose estimate is NaN/inf counts as a *failure*
  at every threshold, so a method cannot gain by refusing to answer;
* **MAE / RMSE**: over evaluated pixels with a finite estimate (a missing estimate has no error
  to average); ``n_invalid_estimates`` says how many were left out;
* **boundary region**: pixels within ``radius_px`` (5) of a ground-truth boundary pixel of
  :func:`~tof_mpd_ros.correction.edges.ground_truth_edges`, by Euclidean distance transform;
* **pooling over frames**: counts and sums are added over all pixels of all frames (the paper's
  pixel-pooled percentages), not averaged per frame;
* **edge matching**: a predicted edge pixel is correct when a ground-truth edge pixel lies within
  ``tolerance_px`` (Euclidean, distance transform), and a ground-truth pixel is recalled when a
  predicted pixel lies within ``tolerance_px``. This is the distance-transform tolerance of
  edge benchmarks without BSDS's one-to-one assignment: thinned (NMS) maps keep the difference
  small, and it needs no matching library. A score of 0 is never an edge; a prediction is
  ``score >= threshold``. With no prediction, precision is 1; with no ground truth, recall is 1.

All results are frozen dataclasses with ``to_dict()`` returning JSON-serialisable dicts.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..errors import InputError
from ..validation import check_array, check_same_shape
from .uncertainty import (
    COVERAGE_K,
    coverage,
    flag_precision_recall,
    gaussian_coverage,
    reliability_curve,
)

DEFAULT_THRESHOLDS_MM: tuple[float, ...] = tuple(float(t) for t in range(1, 21))
BOUNDARY_RADIUS_PX = 5


def _finite_or_none(x: float) -> float | None:
    """JSON has no NaN: undefined statistics are written as null."""
    return float(x) if np.isfinite(x) else None


def _check_thresholds(thresholds: Sequence[float] | np.ndarray) -> np.ndarray:
    t = check_array("thresholds", thresholds, ndim=1, dtype_kind="fiu").astype(np.float64)
    if t.size == 0 or not np.isfinite(t).all():
        raise InputError(f"thresholds: expected a non-empty 1-D array of finite values, got {t}")
    return t


@dataclass(frozen=True)
class AccuracyCurve:
    """Accuracy against threshold for one region, pooled over the frames it was built from.

    Attributes:
        thresholds_mm: (T,) thresholds in mm.
        accuracy: (T,) fraction in [0, 1] of evaluated pixels with |error| < threshold (NaN when
            no pixel was evaluated).
        n_pixels: evaluated pixels (reference finite, in the region).
        n_invalid_estimates: evaluated pixels whose estimate was not finite (failures).
        mae_mm: mean |error| in mm over evaluated pixels with a finite estimate.
        rmse_mm: root-mean-square error in mm over the same pixels.
    """

    thresholds_mm: tuple[float, ...]
    accuracy: tuple[float, ...]
    n_pixels: int
    n_invalid_estimates: int
    mae_mm: float
    rmse_mm: float

    def at(self, threshold_mm: float) -> float:
        """Accuracy at one of the curve's thresholds."""
        try:
            return self.accuracy[self.thresholds_mm.index(float(threshold_mm))]
        except ValueError as err:
            raise InputError(f"threshold {threshold_mm} mm is not on this curve "
                             f"{self.thresholds_mm}") from err

    def to_dict(self) -> dict:
        return {"thresholds_mm": list(self.thresholds_mm),
                "accuracy": [_finite_or_none(a) for a in self.accuracy],
                "n_pixels": self.n_pixels, "n_invalid_estimates": self.n_invalid_estimates,
                "mae_mm": _finite_or_none(self.mae_mm), "rmse_mm": _finite_or_none(self.rmse_mm)}


@dataclass
class _Tally:
    """Running sums from which an :class:`AccuracyCurve` is formed (pixel pooling)."""

    thresholds: np.ndarray
    correct: np.ndarray = field(init=False)
    n: int = 0
    n_invalid: int = 0
    sum_abs: float = 0.0
    sum_sq: float = 0.0

    def __post_init__(self) -> None:
        self.correct = np.zeros(self.thresholds.size, np.int64)

    def add(self, estimate: np.ndarray, reference: np.ndarray, mask: np.ndarray | None) -> None:
        evaluated = np.isfinite(reference) if mask is None else np.isfinite(reference) & mask
        err = np.abs(estimate[evaluated].astype(np.float64) - reference[evaluated])
        finite = np.isfinite(err)
        self.n += int(err.size)
        self.n_invalid += int(err.size - finite.sum())
        err = err[finite]
        self.sum_abs += float(err.sum())
        self.sum_sq += float(np.square(err).sum())
        # NaN/inf errors were dropped above, so they count as failures at every threshold.
        self.correct += np.searchsorted(np.sort(err), self.thresholds, side="left")

    def curve(self) -> AccuracyCurve:
        n_finite = self.n - self.n_invalid
        acc = self.correct / self.n if self.n else np.full(self.thresholds.size, np.nan)
        return AccuracyCurve(
            thresholds_mm=tuple(float(t) for t in self.thresholds),
            accuracy=tuple(float(a) for a in acc), n_pixels=self.n,
            n_invalid_estimates=self.n_invalid,
            mae_mm=self.sum_abs / n_finite if n_finite else float("nan"),
            rmse_mm=float(np.sqrt(self.sum_sq / n_finite)) if n_finite else float("nan"))


def _check_pair(estimate: object, reference: object) -> tuple[np.ndarray, np.ndarray]:
    est = check_array("estimate", estimate, ndim=2, dtype_kind="fiu")
    ref = check_array("reference", reference, ndim=2, dtype_kind="fiu")
    check_same_shape(estimate=est, reference=ref)
    return est, ref


def accuracy_curve(estimate: np.ndarray, reference: np.ndarray,
                   thresholds: Sequence[float] | np.ndarray = DEFAULT_THRESHOLDS_MM,
                   mask: np.ndarray | None = None) -> AccuracyCurve:
    """The paper's metric for one frame.

    Args:
        estimate: (H, W) float range in mm (any method's output); NaN = no answer (a failure).
        reference: (H, W) float reference range in mm; NaN = missing (not evaluated).
        thresholds: (T,) thresholds in mm (default 1..20).
        mask: optional (H, W) bool region to evaluate (e.g. :func:`boundary_region`).

    Returns:
        The :class:`AccuracyCurve` (MAE and RMSE included).
    """
    est, ref = _check_pair(estimate, reference)
    m = None
    if mask is not None:
        m = check_array("mask", mask, ndim=2, shape=ref.shape, dtype_kind="bui").astype(bool)
    tally = _Tally(_check_thresholds(thresholds))
    tally.add(est, ref, m)
    return tally.curve()


def _distance_to(pixels: np.ndarray) -> np.ndarray:
    """(H, W) float32 Euclidean distance (px) to the nearest True pixel; inf when none."""
    if not pixels.any():
        return np.full(pixels.shape, np.inf, np.float32)
    return cv2.distanceTransform((~pixels).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def boundary_region(reference_mm: np.ndarray, radius_px: float = BOUNDARY_RADIUS_PX, *,
                    edges: np.ndarray | None = None) -> np.ndarray:
    """Pixels within ``radius_px`` of a ground-truth boundary pixel (the paper: 5 px).

    Args:
        reference_mm: (H, W) float reference range in mm, NaN = missing.
        radius_px: Euclidean radius in pixels (inclusive).
        edges: optional (H, W) bool boundary pixels; default
            :func:`~tof_mpd_ros.correction.edges.ground_truth_edges` of ``reference_mm``.

    Returns:
        (H, W) bool region (all False when the frame has no boundary).
    """
    ref = check_array("reference_mm", reference_mm, ndim=2, dtype_kind="fiu")
    if not (np.isfinite(radius_px) and radius_px >= 0):
        raise InputError(f"radius_px: expected a finite value >= 0, got {radius_px!r}")
    if edges is None:
        # Imported here: the correction package pulls in torch, which metrics do not need.
        from ..correction.edges import ground_truth_edges

        edges, _ = ground_truth_edges(ref)
    else:
        edges = check_array("edges", edges, ndim=2, shape=ref.shape, dtype_kind="bui")
    return _distance_to(edges.astype(bool)) <= radius_px


@dataclass(frozen=True)
class FrameEvaluation:
    """Pixel-pooled accuracy over many frames, whole image and boundary region."""

    whole: AccuracyCurve
    boundary: AccuracyCurve
    n_frames: int
    radius_px: float

    def to_dict(self) -> dict:
        return {"whole": self.whole.to_dict(), "boundary": self.boundary.to_dict(),
                "n_frames": self.n_frames, "boundary_radius_px": self.radius_px}


def _frames(name: str, frames: object) -> list[np.ndarray]:
    """(N, H, W) array, one (H, W) array or a sequence of (H, W) arrays -> list of (H, W)."""
    if isinstance(frames, np.ndarray):
        a = check_array(name, frames, ndim=(2, 3), dtype_kind="fiub")
        return [a] if a.ndim == 2 else list(a)
    if isinstance(frames, Sequence) and not isinstance(frames, (str, bytes)):
        return [check_array(f"{name}[{i}]", f, ndim=2, dtype_kind="fiub")
                for i, f in enumerate(frames)]
    raise InputError(f"{name}: expected an (N, H, W) array or a sequence of (H, W) arrays, "
                     f"got {type(frames).__name__}")


def evaluate_frames(estimates: np.ndarray | Sequence[np.ndarray],
                    references: np.ndarray | Sequence[np.ndarray],
                    thresholds: Sequence[float] | np.ndarray = DEFAULT_THRESHOLDS_MM, *,
                    radius_px: float = BOUNDARY_RADIUS_PX,
                    boundary_masks: Sequence[np.ndarray] | np.ndarray | None = None,
                    ) -> FrameEvaluation:
    """Accuracy curves pooled over all pixels of many frames (paper Fig. 5 and 8).

    Args:
        estimates: N frames of (H, W) float range in mm (an (N, H, W) array or a list; frames
            may differ in size from each other but not from their reference).
        references: N matching reference frames, NaN = missing.
        thresholds: (T,) thresholds in mm (default 1..20).
        radius_px: boundary-region radius (5 px).
        boundary_masks: optional N (H, W) bool boundary regions, e.g. precomputed once for
            several methods; default :func:`boundary_region` of each reference.

    Returns:
        :class:`FrameEvaluation` with whole-image and boundary-region curves.
    """
    est, ref = _frames("estimates", estimates), _frames("references", references)
    if len(est) != len(ref):
        raise InputError(f"estimates and references: expected the same number of frames, got "
                         f"{len(est)} and {len(ref)}")
    masks = None if boundary_masks is None else _frames("boundary_masks", boundary_masks)
    if masks is not None and len(masks) != len(ref):
        raise InputError(f"boundary_masks: expected {len(ref)} frames, got {len(masks)}")
    acc = FrameAccumulator(thresholds, radius_px=radius_px)
    for i, (e, r) in enumerate(zip(est, ref, strict=True)):
        acc.add(e, r, None if masks is None else masks[i])
    return acc.result()


class FrameAccumulator:
    """:func:`evaluate_frames` one frame at a time, so no frame has to be kept in memory.

    ``acc.add(estimate, reference, mask)`` for each frame, then ``acc.result()``; the result is
    identical to ``evaluate_frames`` over the same frames.

    Args:
        thresholds: (T,) thresholds in mm (default 1..20).
        radius_px: boundary-region radius (5 px), used when ``add`` gets no mask.
    """

    def __init__(self, thresholds: Sequence[float] | np.ndarray = DEFAULT_THRESHOLDS_MM, *,
                 radius_px: float = BOUNDARY_RADIUS_PX) -> None:
        t = _check_thresholds(thresholds)
        self.radius_px = float(radius_px)
        self._whole, self._boundary = _Tally(t), _Tally(t)
        self.n_frames = 0

    def add(self, estimate: np.ndarray, reference: np.ndarray,
            boundary_mask: np.ndarray | None = None) -> None:
        """Pool one frame.

        Args:
            estimate: (H, W) float range in mm, NaN = no answer (a failure).
            reference: (H, W) float reference range in mm, NaN = missing.
            boundary_mask: (H, W) bool boundary region; default :func:`boundary_region`.
        """
        e, r = _check_pair(estimate, reference)
        m = (boundary_region(r, self.radius_px) if boundary_mask is None
             else np.asarray(boundary_mask).astype(bool))
        check_same_shape(reference=r, boundary_mask=m)
        self._whole.add(e, r, None)
        self._boundary.add(e, r, m)
        self.n_frames += 1

    def result(self) -> FrameEvaluation:
        """The pooled :class:`FrameEvaluation` of the frames added so far."""
        return FrameEvaluation(self._whole.curve(), self._boundary.curve(), self.n_frames,
                               self.radius_px)


@dataclass(frozen=True)
class EdgePRCurve:
    """Edge precision / recall over a threshold sweep, pooled over frames.

    Attributes:
        thresholds: (T,) score thresholds (a prediction is ``score >= t``).
        precision, recall, f1: (T,) values in [0, 1].
        tolerance_px: matching distance in pixels.
        n_gt: ground-truth edge pixels (pooled).
    """

    thresholds: tuple[float, ...]
    precision: tuple[float, ...]
    recall: tuple[float, ...]
    f1: tuple[float, ...]
    tolerance_px: float
    n_gt: int

    @property
    def best_index(self) -> int:
        return int(np.argmax(self.f1))

    @property
    def max_f1(self) -> float:
        return self.f1[self.best_index]

    @property
    def best_threshold(self) -> float:
        return self.thresholds[self.best_index]

    def to_dict(self) -> dict:
        return {"thresholds": list(self.thresholds), "precision": list(self.precision),
                "recall": list(self.recall), "f1": list(self.f1),
                "tolerance_px": self.tolerance_px, "n_gt": self.n_gt,
                "max_f1": self.max_f1, "best_threshold": self.best_threshold}


def edge_precision_recall(scores: np.ndarray | Sequence[np.ndarray],
                          gt_edges: np.ndarray | Sequence[np.ndarray],
                          thresholds: Sequence[float] | np.ndarray, tolerance_px: float = 2.0,
                          *, valid: np.ndarray | Sequence[np.ndarray] | None = None,
                          ) -> EdgePRCurve:
    """Precision / recall of thresholded edge scores against ground-truth edges (paper Fig. 10).

    Args:
        scores: (H, W) float edge score (e.g. the NMS strength of
            :func:`~tof_mpd_ros.correction.edges.edge_map_from_responses`, or
            :func:`~tof_mpd_ros.correction.edges.canny_score_map`), or N of them.
        gt_edges: (H, W) bool ground-truth edges, or N of them.
        thresholds: (T,) score thresholds to sweep.
        tolerance_px: matching distance in pixels (inclusive, Euclidean).
        valid: optional (H, W) bool (or N): only these pixels count, as predictions and as
            ground truth (e.g. where the reference is not missing).

    Returns:
        :class:`EdgePRCurve` with precision, recall, F1 per threshold and the max F1.
    """
    s_list, g_list = _frames("scores", scores), _frames("gt_edges", gt_edges)
    v_list = None if valid is None else _frames("valid", valid)
    if len(s_list) != len(g_list) or (v_list is not None and len(v_list) != len(s_list)):
        raise InputError(f"scores, gt_edges and valid: expected the same number of frames, got "
                         f"{len(s_list)}, {len(g_list)}, {None if v_list is None else len(v_list)}")
    if not (np.isfinite(tolerance_px) and tolerance_px >= 0):
        raise InputError(f"tolerance_px: expected a finite value >= 0, got {tolerance_px!r}")
    t = _check_thresholds(thresholds)
    n_pred, ok_pred, n_gt, ok_gt = (np.zeros(t.size, np.int64) for _ in range(4))
    for i, (s, g) in enumerate(zip(s_list, g_list, strict=True)):
        check_same_shape(scores=s, gt_edges=g)
        v = np.ones(s.shape, bool) if v_list is None else v_list[i].astype(bool)
        check_same_shape(scores=s, valid=v)
        gt = g.astype(bool) & v
        near_gt = _distance_to(gt) <= tolerance_px
        score = np.nan_to_num(s.astype(np.float64), nan=0.0)
        for j, thr in enumerate(t):
            pred = (score >= thr) & (score > 0) & v
            n_pred[j] += int(pred.sum())
            ok_pred[j] += int((pred & near_gt).sum())
            n_gt[j] += int(gt.sum())
            ok_gt[j] += int((gt & (_distance_to(pred) <= tolerance_px)).sum())
    precision = np.where(n_pred > 0, ok_pred / np.maximum(n_pred, 1), 1.0)
    recall = np.where(n_gt > 0, ok_gt / np.maximum(n_gt, 1), 1.0)
    denom = precision + recall
    f1 = np.where(denom > 0, 2 * precision * recall / np.where(denom > 0, denom, 1.0), 0.0)
    return EdgePRCurve(tuple(float(x) for x in t), tuple(float(x) for x in precision),
                       tuple(float(x) for x in recall), tuple(float(x) for x in f1),
                       float(tolerance_px), int(n_gt[0]))


class SigmaCoverage:
    """How well a predicted per-pixel σ describes the error, pooled over frames: the fraction of
    scored pixels with ``|estimate - reference| <= k σ`` for k = 1, 2, 3 (a calibrated
    Gaussian σ gives 68.3 / 95.4 / 99.7 %), the reliability curve, and with ``max_sigma_mm``
    the precision / recall of "σ > max_sigma_mm" as a detector of "|error| > 10 mm"
    (:mod:`.uncertainty`, which computes each).

    Scored pixels: reference, estimate and σ all finite (a pixel without a prediction has no σ
    to check). ``add(estimate, sigma, reference)`` per frame, then ``result()``. Keeps the
    scored errors and σ (float32, 8 bytes per pixel).
    """

    def __init__(self, ks: Sequence[float] = COVERAGE_K,
                 max_sigma_mm: float | None = None) -> None:
        self.ks = tuple(float(k) for k in ks)
        self.max_sigma_mm = max_sigma_mm
        self._errors: list[np.ndarray] = []
        self._sigmas: list[np.ndarray] = []

    def add(self, estimate_mm: np.ndarray, sigma_mm: np.ndarray,
            reference_mm: np.ndarray) -> None:
        """Pool one frame: (H, W) float estimate, σ and reference, mm (NaN = none)."""
        e, r = _check_pair(estimate_mm, reference_mm)
        s = check_array("sigma_mm", sigma_mm, shape=r.shape, dtype_kind="fiu")
        with np.errstate(invalid="ignore"):
            err = e.astype(np.float64) - r
        scored = np.isfinite(err) & np.isfinite(s)
        self._errors.append(err[scored].astype(np.float32))
        self._sigmas.append(np.asarray(s[scored], np.float32))

    def pooled(self) -> tuple[np.ndarray, np.ndarray]:
        """(errors, σ) of every scored pixel so far, (M,) float32 mm each."""
        if not self._errors:
            return np.zeros(0, np.float32), np.zeros(0, np.float32)
        return np.concatenate(self._errors), np.concatenate(self._sigmas)

    def result(self) -> dict[str, object]:
        """``{"k", "observed" (fractions, None without a scored pixel), "gaussian" (the
        fraction a Gaussian puts within k σ), "pixels", "median_sigma_mm", "reliability"
        (:func:`.uncertainty.reliability_curve` as lists), "flags" (with ``max_sigma_mm``)}``."""
        err, sigma = self.pooled()
        cover = coverage(err, sigma, self.ks)
        curve = reliability_curve(err, sigma)
        out: dict[str, object] = {
            "k": list(self.ks),
            "observed": [None if math.isnan(v) else v for v in cover.values()],
            "gaussian": [gaussian_coverage(k) for k in self.ks],
            "pixels": int(err.size),
            "median_sigma_mm": float(np.median(sigma)) if sigma.size else None,
            "reliability": {"sigma_rms_mm": curve.sigma_rms_mm.tolist(),
                            "error_rms_mm": curve.error_rms_mm.tolist(),
                            "count": curve.count.tolist()}}
        if self.max_sigma_mm is not None:
            out["flags"] = {k: _finite_or_none(v) for k, v in flag_precision_recall(
                err, sigma, self.max_sigma_mm).items()}
        return out
