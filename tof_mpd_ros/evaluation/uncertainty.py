"""Is a predicted per-pixel σ calibrated? Coverage, a reliability curve, and whether the pixels
flagged as unreliable are the wrong ones (issue 17, item 2).

* **Coverage** at k σ: the fraction of pixels with ``|error| <= k σ``. For a calibrated
  Gaussian prediction it is erf(k / √2): 68.3 / 95.4 / 99.7 % for k = 1, 2, 3.
* **Reliability curve**: the pixels sorted into bins of predicted σ (equal counts), and per
  bin the RMS of the actual error against the bin's RMS σ. Calibrated predictions lie on the
  diagonal; above it, over-confident; below, under-confident.
* **Flags**: "σ > max_sigma_mm" (the pixels the model is unsure of: the corrector gives them a
  neighbour's side or invalidates them) against "|error| > 10 mm" of the network's own range:
  precision (of the flagged pixels, the share that are wrong) and recall (of the wrong
  pixels, the share flagged).

Every function takes flat or image-shaped arrays of errors (mm, estimate − reference) and σ
(mm); pixels where either is not finite are left out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

#: the k of the coverage report and each one's Gaussian expectation
COVERAGE_K = (1.0, 2.0, 3.0)
#: "wrong" for the flags' precision / recall, mm
WRONG_MM = 10.0


def gaussian_coverage(k: float) -> float:
    """P(|z| <= k) for a standard normal z."""
    return math.erf(k / math.sqrt(2.0))


def _pairs(errors_mm: np.ndarray, sigma_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    e = np.asarray(errors_mm, np.float64).ravel()
    s = np.asarray(sigma_mm, np.float64).ravel()
    if e.shape != s.shape:
        raise InputError(f"errors ({np.shape(errors_mm)}) and sigma ({np.shape(sigma_mm)}) "
                         "differ in size")
    ok = np.isfinite(e) & np.isfinite(s)
    return e[ok], s[ok]


def coverage(errors_mm: np.ndarray, sigma_mm: np.ndarray,
             ks: Sequence[float] = COVERAGE_K) -> dict[str, float]:
    """``{"1": fraction within 1 σ, ...}`` (NaN when no pixel has both values)."""
    e, s = _pairs(errors_mm, sigma_mm)
    return {f"{k:g}": float(np.mean(np.abs(e) <= k * s)) if e.size else math.nan for k in ks}


@dataclass(frozen=True)
class ReliabilityCurve:
    """Per bin of predicted σ (equal pixel counts): RMS σ and RMS actual error, mm, and the
    pixel count. Arrays (n_bins,) float64 / int64."""

    sigma_rms_mm: np.ndarray
    error_rms_mm: np.ndarray
    count: np.ndarray


def reliability_curve(errors_mm: np.ndarray, sigma_mm: np.ndarray,
                      n_bins: int = 10) -> ReliabilityCurve:
    """The reliability curve of the module docstring (fewer bins when pixels are few)."""
    e, s = _pairs(errors_mm, sigma_mm)
    if n_bins < 1:
        raise InputError(f"n_bins must be >= 1, got {n_bins}")
    if e.size == 0:
        empty = np.zeros(0)
        return ReliabilityCurve(empty, empty, np.zeros(0, np.int64))
    order = np.argsort(s, kind="stable")
    parts = [p for p in np.array_split(order, min(n_bins, e.size)) if p.size]
    return ReliabilityCurve(np.array([np.sqrt(np.mean(s[p] ** 2)) for p in parts]),
                            np.array([np.sqrt(np.mean(e[p] ** 2)) for p in parts]),
                            np.array([p.size for p in parts], np.int64))


def flag_precision_recall(errors_mm: np.ndarray, sigma_mm: np.ndarray, max_sigma_mm: float,
                          wrong_mm: float = WRONG_MM) -> dict[str, float]:
    """Precision and recall of "σ > max_sigma_mm" as a detector of "|error| > wrong_mm", and
    the flagged share (NaN where undefined: nothing flagged / nothing wrong)."""
    e, s = _pairs(errors_mm, sigma_mm)
    flagged, wrong = s > max_sigma_mm, np.abs(e) > wrong_mm
    hits = int(np.sum(flagged & wrong))
    return {"precision": hits / int(flagged.sum()) if flagged.any() else math.nan,
            "recall": hits / int(wrong.sum()) if wrong.any() else math.nan,
            "flagged_fraction": float(flagged.mean()) if e.size else math.nan,
            "wrong_fraction": float(wrong.mean()) if e.size else math.nan}


def plot_reliability(curve: ReliabilityCurve, cover: dict[str, float], path: str | Path, *,
                     title: str | None = None, dpi: int = 120) -> Path:
    """Reliability curve (left, log-log, diagonal = calibrated) and coverage against the
    Gaussian expectation (right); writes a PNG and returns its path."""
    from matplotlib.figure import Figure

    from .plots import save_png

    fig = Figure(figsize=(9, 4))
    left, right = fig.subplots(1, 2)
    if curve.count.size:
        lo = float(min(curve.sigma_rms_mm.min(), curve.error_rms_mm.min(), 0.3))
        hi = float(max(curve.sigma_rms_mm.max(), curve.error_rms_mm.max(), 3.0))
        left.plot([lo, hi], [lo, hi], color="grey", lw=1, label="calibrated")
        left.plot(curve.sigma_rms_mm, curve.error_rms_mm, marker="o", label="model")
        left.set(xscale="log", yscale="log")
    left.set(xlabel="predicted σ, RMS per bin (mm)", ylabel="actual error, RMS per bin (mm)",
             title="reliability")
    left.legend(loc="upper left", fontsize="small")
    ks = [float(k) for k in cover]
    right.bar([k - 0.15 for k in ks], [100 * gaussian_coverage(k) for k in ks], width=0.3,
              color="grey", label="Gaussian")
    right.bar([k + 0.15 for k in ks], [100 * v for v in cover.values()], width=0.3,
              label="model")
    right.set(xticks=ks, xticklabels=[f"{k:g}σ" for k in ks], ylim=(0, 100),
              ylabel="pixels with |error| ≤ kσ (%)", title="coverage")
    right.legend(loc="lower right", fontsize="small")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save_png(fig, path, dpi)
