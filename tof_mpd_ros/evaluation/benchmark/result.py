"""What the benchmark measured (:class:`BenchmarkResult`) and its JSON form."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..components import ComponentEvaluation
from ..metrics import FrameEvaluation
from .config import BASELINE_NAMES, TABLE_THRESHOLDS_MM, methods_for, own_method
from .split import TrainValSplit
from .tuning import TunedBaseline


@dataclass
class BenchmarkResult:
    """Everything the benchmark measured.

    Attributes:
        methods: method -> pooled accuracy curves (whole, boundary) on the test frames.
        seconds_per_frame: method -> median wall time per frame (s), calibration included.
        tuned: baseline name -> :class:`TunedBaseline`.
        components: the component analysis and G-vs-Canny edge curves on the same frames.
        split: the train/validation split.
        comparison: :func:`~.paper.compare_with_paper` output.
        diagnostics: error decomposition and context numbers.
        examples: per example frame: ``index``, ``reference``, ``amplitude``, ``estimates``
            (method -> (H, W) mm), ``edges_g``, ``line`` (:class:`~..profiles.ProfileLine` or None),
            ``profiles`` (method -> (L,) mm, ``reference`` included).
        n_frames: test frames evaluated; n_skipped: test frames without a reference.
        timings: stage -> seconds of the benchmark run itself.
        info: provenance (machine, config).
        kind: the model's kind, ``"patch"`` (methods ``F`` and ``proposed``) or ``"fcn"``
            (method ``fcn``).
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
    kind: str = "patch"

    @property
    def proposed(self) -> str:
        """The method name of the model's full output: ``proposed`` or ``fcn``."""
        return own_method(self.kind)

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
            "model_kind": self.kind, "proposed_method": self.proposed,
            "methods_order": [m for m in methods_for(self.kind) if m in self.methods],
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
