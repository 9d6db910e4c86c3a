"""Figures of the paper's evaluation: accuracy curves, edge precision / recall, error maps.

Each function draws on its own :class:`matplotlib.figure.Figure` (Agg canvas, no pyplot state,
safe from worker threads and headless machines), writes a PNG and returns its path.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from ..errors import InputError
from ..validation import check_array, check_same_shape
from .metrics import AccuracyCurve, EdgePRCurve, FrameEvaluation

MISSING_COLOUR = "#22aa22"  # the paper marks missing reference pixels in green
NO_ESTIMATE_COLOUR = "#000000"


def save_png(fig: Figure, path: str | Path, dpi: int) -> Path:
    """Write ``fig`` as a PNG (parent directories created) on an Agg canvas; the one figure
    writer of the evaluation's plots."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(out, dpi=dpi, format="png")
    return out


def _curve_panel(ax, curves: Mapping[str, AccuracyCurve], title: str) -> None:
    for name, curve in curves.items():
        ax.plot(curve.thresholds_mm, 100.0 * np.asarray(curve.accuracy, dtype=float),
                marker=".", label=name)
    ax.set(title=title, xlabel="threshold (mm)", ylabel="correct pixels (%)", ylim=(0, 100))
    ax.grid(True, alpha=0.3)
    ax.legend(loc="lower right", fontsize="small")


def plot_accuracy_curves(evaluations: Mapping[str, FrameEvaluation], path: str | Path, *,
                         title: str | None = None, dpi: int = 120) -> Path:
    """Accuracy vs threshold for several methods, whole image (left) and boundary region (right).

    Args:
        evaluations: method name -> :class:`FrameEvaluation` (same thresholds for all).
        path: PNG file to write (parent directories are created).
        title: optional figure title.
        dpi: resolution.

    Returns:
        The written path.
    """
    if not evaluations:
        raise InputError("evaluations: expected at least one method, got none")
    fig = Figure(figsize=(10, 4), layout="constrained")
    left, right = fig.subplots(1, 2)
    _curve_panel(left, {n: e.whole for n, e in evaluations.items()}, "whole image")
    radius = next(iter(evaluations.values())).radius_px
    _curve_panel(right, {n: e.boundary for n, e in evaluations.items()},
                 f"boundary region ({radius:g} px)")
    if title:
        fig.suptitle(title)
    return save_png(fig, path, dpi)


def plot_precision_recall(curves: Mapping[str, EdgePRCurve], path: str | Path, *,
                          title: str | None = None, dpi: int = 120) -> Path:
    """Edge precision-recall curves with each method's maximum-F1 point marked.

    Args:
        curves: method name -> :class:`EdgePRCurve`.
        path: PNG file to write.
        title: optional axes title.
        dpi: resolution.

    Returns:
        The written path.
    """
    if not curves:
        raise InputError("curves: expected at least one method, got none")
    fig = Figure(figsize=(5, 5), layout="constrained")
    ax = fig.subplots()
    grid = np.linspace(0.01, 1.0, 100)
    for f in (0.2, 0.4, 0.6, 0.8):  # iso-F1 contours, for reading the curves
        r = grid[grid > f / (2 - f)]
        ax.plot(r, f * r / (2 * r - f), color="0.85", linewidth=0.8, zorder=0)
    for name, c in curves.items():
        (line,) = ax.plot(c.recall, c.precision, label=f"{name} (max F1 {c.max_f1:.3f})")
        ax.plot(c.recall[c.best_index], c.precision[c.best_index], "o",
                color=line.get_color(), markersize=7)
    ax.set(xlabel="recall", ylabel="precision", xlim=(0, 1), ylim=(0, 1.01),
           title=title or f"edges, tolerance {next(iter(curves.values())).tolerance_px:g} px")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="lower left", fontsize="small")
    return save_png(fig, path, dpi)


def plot_error_map(estimate: np.ndarray, reference: np.ndarray, path: str | Path, *,
                   limit_mm: float = 20.0, title: str | None = None, dpi: int = 120) -> Path:
    """Signed error map ``estimate - reference`` on a diverging scale (white = correct).

    Missing reference pixels are green (as in the paper), pixels with no estimate black.

    Args:
        estimate: (H, W) float range in mm, NaN = no estimate.
        reference: (H, W) float reference range in mm, NaN = missing.
        path: PNG file to write.
        limit_mm: colour scale saturates at +- this many mm.
        title: optional axes title.
        dpi: resolution.

    Returns:
        The written path.
    """
    est = check_array("estimate", estimate, ndim=2, dtype_kind="fiu").astype(np.float64)
    ref = check_array("reference", reference, ndim=2, dtype_kind="fiu").astype(np.float64)
    check_same_shape(estimate=est, reference=ref)
    if not (np.isfinite(limit_mm) and limit_mm > 0):
        raise InputError(f"limit_mm: expected a finite value > 0, got {limit_mm!r}")
    missing = ~np.isfinite(ref)
    no_estimate = ~missing & ~np.isfinite(est)
    error = np.ma.masked_invalid(est - ref)
    fig = Figure(figsize=(6, 4.5), layout="constrained")
    ax = fig.subplots()
    image = ax.imshow(error, cmap="RdBu_r", vmin=-limit_mm, vmax=limit_mm,
                      interpolation="nearest")
    for mask, colour in ((missing, MISSING_COLOUR), (no_estimate, NO_ESTIMATE_COLOUR)):
        if mask.any():
            ax.imshow(np.ma.masked_where(~mask, mask), cmap=ListedColormap([colour]),
                      interpolation="nearest")
    fig.colorbar(image, ax=ax, label="estimate - reference (mm)", extend="both")
    ax.legend(handles=[Patch(color=MISSING_COLOUR, label="reference missing"),
                       Patch(color=NO_ESTIMATE_COLOUR, label="no estimate")],
              loc="upper center", bbox_to_anchor=(0.5, -0.02), ncol=2, fontsize="small",
              frameon=False)
    ax.set(title=title or "range error", xticks=[], yticks=[])
    return save_png(fig, path, dpi)
