"""Grid search of a baseline's free parameters on held-out frames (the paper: "We performed grid
search and used the best one to report the performance").

The default score is the paper's metric at 5 mm: the fraction of reference pixels whose corrected
range is within (strictly less than) 5 mm of the reference, pooled over all validation frames.
Pixels with a missing (NaN) reference are excluded; a valid reference pixel that the method left
NaN (invalid ToF input) counts as a miss, so every method is scored on the same pixels. These
are the definitions of :mod:`tof_mpd_ros.evaluation.metrics` (a test keeps the two in step);
the count is done here so a grid search needs only two integers per frame and combination.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from ...errors import InputError
from .base import Baseline, FrameLike

# score(estimate (H, W) mm, reference (H, W) mm) -> (hits, counted); pooled = Σ hits / Σ counted.
PixelScore = Callable[[np.ndarray, np.ndarray], tuple[float, float]]


def within_threshold(estimate: np.ndarray, reference: np.ndarray,
                     threshold_mm: float = 5.0) -> tuple[float, float]:
    """``(hits, counted)``: reference pixels with |estimate − reference| < threshold, and all
    pixels with a finite reference. Both arrays (H, W) radial range in mm."""
    ref_ok = np.isfinite(reference)
    with np.errstate(invalid="ignore"):
        hits = np.abs(estimate - reference) < threshold_mm
    return float(np.count_nonzero(hits & ref_ok)), float(np.count_nonzero(ref_ok))


def _plain(value: Any) -> Any:
    """JSON-friendly copy of a parameter value (numpy scalars to Python)."""
    return value.item() if isinstance(value, np.generic) else value


def _combos(grid: Mapping[str, Sequence[Any]]) -> list[dict[str, Any]]:
    keys = list(grid)
    return [dict(zip(keys, vals, strict=True)) for vals in itertools.product(*grid.values())]


def _split(method: Baseline, grid: Mapping[str, Sequence[Any]]
           ) -> tuple[dict[str, Sequence[Any]], dict[str, Sequence[Any]]]:
    """Split a grid into (fit-time, apply-time) parts; unknown names raise InputError."""
    apply_names = set(method.apply_param_names())
    fit_grid, apply_grid = {}, {}
    for key, values in grid.items():
        if not isinstance(values, Sequence) or isinstance(values, str) or len(values) == 0:
            raise InputError(f"grid for {key!r} must be a non-empty list, got {values!r}")
        if key in apply_names:
            apply_grid[key] = values
        elif key in method.fit_params:
            fit_grid[key] = values
        else:
            raise InputError(f"{method.name} has no parameter {key!r}; apply parameters: "
                             f"{sorted(apply_names)}, fit parameters: {sorted(method.fit_params)}")
    return fit_grid, apply_grid


def grid_search(
    method: Baseline,
    val_frames: Sequence[FrameLike],
    param_grid: Mapping[str, Sequence[Any]] | None = None,
    *,
    train_frames: Sequence[FrameLike] | None = None,
    score: PixelScore = within_threshold,
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Evaluate every combination of ``param_grid`` on ``val_frames`` and pick the best.

    Args:
        method: the baseline; supervised methods must already be fitted unless the grid holds
            fit parameters (then a fresh copy is fitted on ``train_frames`` per combination).
        val_frames: frames with ``range_mm``, ``amplitude`` and ``reference_mm``.
        param_grid: name -> list of values; apply parameters (keywords of ``apply``) and/or fit
            parameters (constructor arguments). Default: ``method.param_grid`` plus
            ``method.fit_param_grid`` when ``train_frames`` is given.
        train_frames: training frames for refitting over fit parameters.
        score: per-frame ``(hits, counted)``; the grid score is Σ hits / Σ counted.

    Returns:
        ``(best_params, table)``: the best combination, and one JSON-serialisable row per
        combination in grid order: ``{"params": {...}, "score": float, "n_pixels": int,
        "seconds_per_frame": float}``. Ties go to the first combination.

    Raises:
        InputError: unknown parameter names, empty grids, no validation reference pixels, or fit
            parameters without ``train_frames`` for a supervised method.
    """
    if param_grid is None:
        param_grid = dict(method.param_grid)
        if train_frames is not None:
            param_grid.update(method.fit_param_grid)
    fit_grid, apply_grid = _split(method, param_grid)
    if fit_grid and method.supervised and train_frames is None:
        raise InputError(f"{method.name}: fit parameters {sorted(fit_grid)} need train_frames")
    refs = [fr.reference_mm for fr in val_frames]
    if not val_frames or any(r is None for r in refs):
        raise InputError("grid_search needs validation frames that all have reference_mm")
    table: list[dict[str, Any]] = []
    for fit_combo in _combos(fit_grid):
        fitted = method
        if fit_combo:
            fitted = type(method)(**{**method.fit_params, **fit_combo})
            fitted.fit(train_frames or [])
        table.extend(_evaluate(fitted, fit_combo, _combos(apply_grid), val_frames, score))
    if sum(row["n_pixels"] for row in table) == 0:
        raise InputError("grid_search: the validation frames have no reference pixels")
    best = max(range(len(table)), key=lambda i: (table[i]["score"], -i))
    return dict(table[best]["params"]), table


def _evaluate(method: Baseline, fit_combo: dict[str, Any], apply_combos: list[dict[str, Any]],
              frames: Sequence[FrameLike], score: PixelScore) -> list[dict[str, Any]]:
    """Rows for every apply combination of one fitted method. Frames are the outer loop so a
    method may cache per-frame work (RF-WF's confidence) across combinations."""
    hits = np.zeros(len(apply_combos))
    counted = np.zeros(len(apply_combos))
    seconds = np.zeros(len(apply_combos))
    for fr in frames:
        for i, combo in enumerate(apply_combos):
            t0 = time.perf_counter()
            est = method.apply(fr.range_mm, fr.amplitude, **combo)
            seconds[i] += time.perf_counter() - t0
            h, c = score(est, np.asarray(fr.reference_mm, np.float32))
            hits[i] += h
            counted[i] += c
    return [{
        "params": {k: _plain(v) for k, v in {**fit_combo, **combo}.items()},
        "score": float(hits[i] / counted[i]) if counted[i] > 0 else 0.0,
        "n_pixels": int(counted[i]),
        "seconds_per_frame": float(seconds[i] / len(frames)),
    } for i, combo in enumerate(apply_combos)]
