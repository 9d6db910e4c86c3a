"""Fitting and grid-searching one baseline on the training frames (the paper: "we performed a
grid search and used the best one to report the performance")."""

from __future__ import annotations

import dataclasses
import itertools
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...errors import InputError
from ..baselines import BASELINES, Baseline, grid_search
from ..baselines.forest import per_frame_quota
from .config import GridSpec
from .split import CalibratedFrame

_EDGE_EXEMPT = frozenset({"n_trees"})


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
