"""Measurements that explain a ranking: where each method misses, and why.

The benchmark's findings quote these instead of reasoning about causes:

* :class:`RegionTally` — accuracy by distance to the ground-truth edges (on the edge, near it,
  interior), so "it blurs the boundaries" is a number in the ≤ 2 px region;
* :func:`edges_by_orientation` — G's edge map against the reference's edges per orientation
  group (which directions G finds, and whether it names them right);
* :class:`NoiseTally` — the calibrated error away from boundaries split into pixel noise and a
  spatially smooth bias (what smoothing can and cannot remove);
* :class:`MissTally` — of a method's misses (|error| ≥ 5 mm or no answer), the share that is
  *noise-limited* (the local mean error over 5 × 5 valid pixels is within 5 mm: averaging would
  have fixed it) and the share *beyond the truncation* of F's target (|reference − calibrated|
  > T: F cannot reach it by construction, whatever its training).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from .metrics import _distance_to

#: regions by distance (px) to the nearest ground-truth edge: (name, lower, upper], inclusive
REGIONS = (("edge (<= 2 px)", -1.0, 2.0), ("near edge (2-5 px)", 2.0, 5.0),
           ("interior (> 5 px)", 5.0, np.inf))


def local_mean(values: np.ndarray, mask: np.ndarray, size: int = 5) -> np.ndarray:
    """(H, W) float32 mean of ``values`` over the ``mask`` pixels of each size × size window
    (0 where the window holds none)."""
    v = np.where(mask, values, 0.0).astype(np.float32)
    w = mask.astype(np.float32)
    k = (size, size)
    num = cv2.boxFilter(v, -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
    den = cv2.boxFilter(w, -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
    return num / np.maximum(den, 1.0)


def edge_distance(gt_edges: np.ndarray) -> np.ndarray:
    """(H, W) float32 distance in px to the nearest ground-truth edge pixel (inf: none)."""
    return _distance_to(np.asarray(gt_edges, bool))


class RegionTally:
    """Per method and region (:data:`REGIONS`): pixels within ``threshold_mm``, MAE, count.

    ``add(estimates, reference, distance)`` per frame (estimates: method -> (H, W) mm, NaN = no
    answer, scored as a miss; reference: (H, W) mm, NaN = not scored; distance: from
    :func:`edge_distance`), then ``result()``.
    """

    def __init__(self, threshold_mm: float = 5.0) -> None:
        self.threshold_mm = float(threshold_mm)
        self._sums: dict[str, dict[str, list[float]]] = {}

    def add(self, estimates: Mapping[str, np.ndarray], reference: np.ndarray,
            distance: np.ndarray) -> None:
        scored = np.isfinite(reference)
        for name, est in estimates.items():
            err = np.abs(np.asarray(est, np.float64) - reference)
            # strictly within, as :class:`~.metrics.FrameAccumulator` counts
            hit = np.isfinite(err) & (err < self.threshold_mm)
            for region, lo, hi in REGIONS:
                m = scored & (distance > lo) & (distance <= hi)
                s = self._sums.setdefault(name, {}).setdefault(region, [0.0, 0.0, 0.0, 0.0])
                s[0] += float(np.count_nonzero(hit & m))
                finite = m & np.isfinite(err)
                s[1] += float(err[finite].sum())
                s[2] += float(np.count_nonzero(finite))
                s[3] += float(np.count_nonzero(m))

    def result(self) -> dict[str, dict[str, dict[str, float]]]:
        """region -> method -> {"within", "mae_mm", "pixels"} (NaN where no pixel)."""
        out: dict[str, dict[str, dict[str, float]]] = {r: {} for r, _, _ in REGIONS}
        for name, regions in self._sums.items():
            for region, (hits, err_sum, n_finite, n) in regions.items():
                out[region][name] = {"within": hits / n if n else float("nan"),
                                     "mae_mm": err_sum / n_finite if n_finite else float("nan"),
                                     "pixels": int(n)}
        return out


#: orientation groups of the edge normals (:func:`~tof_mpd_ros.correction.edges.orientation_group`)
ORIENTATIONS = ("0°", "45°", "90°", "135°")


def edges_by_orientation(pred_edges: Sequence[np.ndarray], pred_groups: Sequence[np.ndarray],
                         gt_edges: Sequence[np.ndarray], gt_groups: Sequence[np.ndarray], *,
                         tolerance_px: float = 2.0) -> dict[str, dict[str, float | int | None]]:
    """Precision and recall of an edge map per orientation group of the edge normal.

    Args:
        pred_edges: N (H, W) bool predicted edges (G's hysteresis map).
        pred_groups: N (H, W) int group 0..3 of each prediction (G's winning head).
        gt_edges: N (H, W) bool reference edges; gt_groups: N (H, W) int their groups.
        tolerance_px: a prediction and a reference edge match within this distance.

    Returns:
        group name -> {"precision": predictions of the group within tolerance of any reference
        edge, "recall": reference edges of the group within tolerance of any prediction,
        "same_group": of the matched predictions, the share whose group is that of the nearest
        reference edge, "n_pred", "n_gt"} (None where there is nothing to count).
    """
    counts = np.zeros((4, 5), np.int64)   # n_pred, ok_pred, same, n_gt, ok_gt
    for pe, pg, ge, gg in zip(pred_edges, pred_groups, gt_edges, gt_groups, strict=True):
        pe, ge = np.asarray(pe, bool), np.asarray(ge, bool)
        if ge.any():
            dist, (iy, ix) = ndimage.distance_transform_edt(~ge, return_indices=True)
            nearest = np.asarray(gg)[iy, ix]
        else:
            dist, nearest = np.full(ge.shape, np.inf), np.full(ge.shape, -1)
        near_pred = (_distance_to(pe) <= tolerance_px) if pe.any() else np.zeros_like(pe)
        matched = pe & (dist <= tolerance_px)
        for g in range(4):
            mine = pe & (np.asarray(pg) == g)
            counts[g] += (mine.sum(), (mine & matched).sum(),
                          (mine & matched & (nearest == g)).sum(),
                          (ge & (np.asarray(gg) == g)).sum(),
                          (ge & (np.asarray(gg) == g) & near_pred).sum())
    out = {}
    for g, name in enumerate(ORIENTATIONS):
        n_pred, ok_pred, same, n_gt, ok_gt = (int(x) for x in counts[g])
        out[name] = {"precision": ok_pred / n_pred if n_pred else None,
                     "recall": ok_gt / n_gt if n_gt else None,
                     "same_group": same / ok_pred if ok_pred else None,
                     "n_pred": n_pred, "n_gt": n_gt}
    return out


class MissTally:
    """Of each method's misses (|error| ≥ ``threshold_mm`` or no answer): how many are
    noise-limited and how many lie beyond the truncation ``clip_mm`` of F's target."""

    def __init__(self, clip_mm: float | None, threshold_mm: float = 5.0, size: int = 5) -> None:
        self.clip_mm = None if clip_mm is None else float(clip_mm)
        self.threshold_mm = float(threshold_mm)
        self.size = int(size)
        self._counts: dict[str, list[int]] = {}
        self.n_scored = self.n_beyond = 0

    def add(self, estimates: Mapping[str, np.ndarray], reference: np.ndarray,
            calibrated: np.ndarray) -> None:
        scored = np.isfinite(reference)
        beyond = np.zeros_like(scored)
        if self.clip_mm is not None:
            with np.errstate(invalid="ignore"):
                beyond = scored & (np.abs(reference - calibrated) > self.clip_mm)
        self.n_scored += int(scored.sum())
        self.n_beyond += int(beyond.sum())
        for name, est in estimates.items():
            err = np.asarray(est, np.float64) - reference
            answered = scored & np.isfinite(err)
            miss = scored & ~(answered & (np.abs(err) < self.threshold_mm))
            smooth = local_mean(np.where(answered, err, 0.0), answered, self.size)
            noisy = miss & answered & (np.abs(smooth) <= self.threshold_mm)
            c = self._counts.setdefault(name, [0, 0, 0])
            c[0] += int(miss.sum())
            c[1] += int(noisy.sum())
            c[2] += int((miss & beyond).sum())

    def result(self) -> dict[str, object]:
        """``{"clip_mm", "beyond_share" (of scored pixels), "methods": {name: {"misses",
        "miss_share", "noise_limited", "beyond_clip"}}}`` — the last two as shares of the
        method's misses."""
        methods = {}
        for name, (miss, noisy, beyond) in self._counts.items():
            methods[name] = {"misses": miss,
                             "miss_share": miss / self.n_scored if self.n_scored else None,
                             "noise_limited": noisy / miss if miss else None,
                             "beyond_clip": beyond / miss if miss and self.clip_mm else None}
        return {"clip_mm": self.clip_mm,
                "beyond_share": self.n_beyond / self.n_scored if self.n_scored else None,
                "methods": methods}


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


__all__ = ["ORIENTATIONS", "REGIONS", "MissTally", "NoiseTally", "RegionTally", "edge_distance",
           "edges_by_orientation", "local_mean"]
