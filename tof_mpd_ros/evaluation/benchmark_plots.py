"""Figures of the benchmark (paper Fig. 5, 6 and 7/8).

* :func:`plot_method_curves`: accuracy against threshold for every method in one plot (one
  region per figure, like the paper's two panels of Fig. 5);
* :func:`plot_qualitative`: reference and each method's range (top row), colour-coded signed
  errors with missing reference pixels in green (bottom row), like Fig. 6;
* :func:`plot_profile`: range values along a line across a boundary, like Fig. 7/8.

Each function draws on its own :class:`~matplotlib.figure.Figure` (Agg, no pyplot state), writes
a PNG and returns its path.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from ..errors import InputError
from .metrics import AccuracyCurve
from .plots import MISSING_COLOUR, NO_ESTIMATE_COLOUR, save_png
from .profiles import ProfileLine

# Fixed styles so a method looks the same in every figure.
_STYLE: dict[str, dict] = {
    "reference": {"color": "black", "linestyle": "--", "linewidth": 1.8},
    "raw": {"color": "0.55", "linestyle": ":", "linewidth": 1.6},
    "calibrated": {"color": "tab:green", "linestyle": "--", "linewidth": 1.6},
    "JBF": {"color": "tab:blue"},
    "WMF": {"color": "tab:cyan"},
    "RF-WF": {"color": "tab:purple"},
    "RFD": {"color": "tab:brown", "linewidth": 1.8},
    "TV": {"color": "tab:olive"},
    "PD": {"color": "tab:pink"},
    "F": {"color": "tab:orange", "linestyle": "-."},
    "proposed": {"color": "tab:red", "linewidth": 2.6},
    "fcn": {"color": "tab:red", "linewidth": 2.6},
}
LABELS = {"F": "F alone", "proposed": "proposed (full)", "fcn": "fcn (U-Net with σ)"}


def _style(name: str) -> dict:
    return {"linewidth": 1.3, **_STYLE.get(name, {})}


def plot_method_curves(curves: Mapping[str, AccuracyCurve], path: str | Path, *,
                       title: str, mark_mm: float = 5.0, dpi: int = 120) -> Path:
    """Accuracy (% of pixels with |error| < t) against t for every method, one region.

    Args:
        curves: method -> :class:`AccuracyCurve` (whole image or boundary region).
        path: PNG to write.
        title: axes title (e.g. "whole image").
        mark_mm: a vertical guide at this threshold (the ranking threshold).
        dpi: resolution.

    Returns:
        The written path.
    """
    if not curves:
        raise InputError("curves: expected at least one method, got none")
    fig = Figure(figsize=(6.4, 4.8), layout="constrained")
    ax = fig.subplots()
    for name, curve in curves.items():
        ax.plot(curve.thresholds_mm, 100.0 * np.asarray(curve.accuracy, dtype=float),
                label=LABELS.get(name, name), **_style(name))
    ax.axvline(mark_mm, color="0.7", linewidth=0.8, zorder=0)
    ax.set(title=title, xlabel="threshold (mm)", ylabel="correctly recovered pixels (%)",
           ylim=(0, 100), xlim=(0, max(max(c.thresholds_mm) for c in curves.values())))
    ax.grid(True, alpha=0.3)
    ax.legend(loc="lower right", fontsize="small", ncol=2)
    return save_png(fig, path, dpi)


def _panel_image(ax, image: np.ndarray, missing: np.ndarray, vmin: float, vmax: float,
                 cmap: str) -> object:
    handle = ax.imshow(np.ma.masked_invalid(image), cmap=cmap, vmin=vmin, vmax=vmax,
                       interpolation="nearest")
    no_value = ~np.isfinite(image) & ~missing
    for mask, colour in ((missing, MISSING_COLOUR), (no_value, NO_ESTIMATE_COLOUR)):
        if mask.any():
            ax.imshow(np.ma.masked_where(~mask, mask), cmap=ListedColormap([colour]),
                      interpolation="nearest")
    ax.set(xticks=[], yticks=[])
    return handle


def _draw_line(ax, line: ProfileLine) -> None:
    (r0, c0), (r1, c1) = (line.row, line.col), line.end
    ax.annotate("", xy=(c1, r1), xytext=(c0, r0),
                arrowprops={"arrowstyle": "->", "color": "red", "linewidth": 1.5})


def plot_qualitative(reference: np.ndarray, estimates: Mapping[str, np.ndarray],
                     path: str | Path, *, line: ProfileLine | None = None,
                     limit_mm: float = 20.0, title: str | None = None, dpi: int = 100) -> Path:
    """Reference and each method's range (top), signed error maps (bottom), like Fig. 6.

    Errors are ``estimate - reference`` on a diverging scale saturating at ``±limit_mm``
    (white = correct, red = range too long e.g. multipath over-shoot, blue = too short). Missing
    reference pixels are green in every panel, pixels without an estimate black.

    Args:
        reference: (H, W) float reference range in mm, NaN = missing.
        estimates: method -> (H, W) float range in mm (NaN = no estimate), in column order.
        path: PNG to write.
        line: optional profile line drawn as a red arrow on the reference.
        limit_mm: error colour scale limit.
        title: figure title.
        dpi: resolution.

    Returns:
        The written path.
    """
    if not estimates:
        raise InputError("estimates: expected at least one method, got none")
    ref = np.asarray(reference, np.float64)
    missing = ~np.isfinite(ref)
    if missing.all():
        raise InputError("reference: every pixel is missing")
    lo, hi = np.percentile(ref[~missing], [1, 99])
    n = len(estimates) + 1
    h, w = ref.shape
    fig = Figure(figsize=(1.9 * n, 2 * 1.9 * h / w + 0.9), layout="constrained")
    axes = fig.subplots(2, n, squeeze=False)
    range_handle = _panel_image(axes[0, 0], ref, missing, lo, hi, "viridis")
    axes[0, 0].set_title("reference", fontsize="small")
    if line is not None:
        _draw_line(axes[0, 0], line)
    axes[1, 0].axis("off")
    axes[1, 0].legend(handles=[Patch(color=MISSING_COLOUR, label="reference missing"),
                               Patch(color=NO_ESTIMATE_COLOUR, label="no estimate")],
                      loc="center", fontsize="x-small", frameon=False)
    err_handle = None
    for j, (name, est) in enumerate(estimates.items(), start=1):
        e = np.asarray(est, np.float64)
        if e.shape != ref.shape:
            raise InputError(f"estimate {name!r} has shape {e.shape}, reference {ref.shape}")
        _panel_image(axes[0, j], e, missing, lo, hi, "viridis")
        axes[0, j].set_title(LABELS.get(name, name), fontsize="small")
        err = np.where(missing, np.nan, e - ref)
        err_handle = _panel_image(axes[1, j], err, missing, -limit_mm, limit_mm, "RdBu_r")
    fig.colorbar(range_handle, ax=axes[0, :].tolist(), label="range (mm)", shrink=0.8,
                 aspect=12)
    fig.colorbar(err_handle, ax=axes[1, :].tolist(), label="error (mm)", extend="both",
                 shrink=0.8, aspect=12)
    if title:
        fig.suptitle(title)
    return save_png(fig, path, dpi)


def plot_profile(profiles: Mapping[str, np.ndarray], methods: Sequence[str], path: str | Path,
                 *, line: ProfileLine | None = None, title: str | None = None,
                 dpi: int = 120) -> Path:
    """Range along a line across a boundary: reference and the given methods (Fig. 7/8).

    Args:
        profiles: name -> (L,) range in mm along the line; must hold ``"reference"``.
        methods: which names of ``profiles`` to draw besides the reference, in legend order.
        path: PNG to write.
        line: the line (for the axis label).
        title: axes title.
        dpi: resolution.

    Returns:
        The written path.
    """
    if "reference" not in profiles:
        raise InputError("profiles: the reference profile is required")
    fig = Figure(figsize=(6.4, 4.0), layout="constrained")
    ax = fig.subplots()
    x = np.arange(len(profiles["reference"]))
    for name in ("reference", *methods):
        if name in profiles:
            ax.plot(x, profiles[name], label=LABELS.get(name, name), **_style(name))
    where = "" if line is None else (f"\n{line.axis} line from row {line.row}, col "
                                     f"{line.col}; reference step {line.step_mm:.0f} mm")
    ax.set(xlabel="position along the line (px)", ylabel="range (mm)")
    ax.set_title((title or "range profile across a boundary") + where, fontsize="medium")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    return save_png(fig, path, dpi)
