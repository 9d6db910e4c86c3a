"""The benchmark's methods, thresholds, baseline grids and settings."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ...correction.fcn import FCNCorrectionModel
from ...correction.pipeline import CorrectionModel
from ...errors import InputError
from ..baselines import BASELINES
from ..metrics import DEFAULT_THRESHOLDS_MM
from ..profiles import DEFAULT_LENGTH_PX

BASELINE_NAMES: tuple[str, ...] = ("JBF", "WMF", "RF-WF", "RFD", "TV", "PD")
PROPOSED = "proposed"
F_ALONE = "F"
#: the method name of a model of the ``"fcn"`` kind (its full output)
FCN = "fcn"
#: the ablation: the full method with the reference's edges in place of G's
REFERENCE_EDGES = "full, reference edges"
#: the methods a model of each kind adds to raw, calibrated and the baselines; the last is its
#: full output, the one ranked against the baselines in the paper's place of the proposed method
MODEL_METHODS: dict[str, tuple[str, ...]] = {"patch": (F_ALONE, PROPOSED), "fcn": (FCN,)}


def methods_for(kind: str) -> tuple[str, ...]:
    """Every method in report order for a model of ``kind`` (``"patch"`` or ``"fcn"``)."""
    return ("raw", "calibrated", *BASELINE_NAMES, *MODEL_METHODS[kind])


def own_method(kind: str) -> str:
    """The method name of a ``kind`` model's full output: ``proposed`` or ``fcn``."""
    return MODEL_METHODS[kind][-1]


# Every method in report order (patch kind); the paper's Fig. 5 compares all but F alone.
METHODS: tuple[str, ...] = methods_for("patch")
PAPER_METHODS: tuple[str, ...] = tuple(m for m in METHODS if m != F_ALONE)
TABLE_THRESHOLDS_MM: tuple[float, ...] = (2.0, 5.0, 10.0)
RANK_THRESHOLD_MM = 5.0
SMOOTHING_BASELINES = ("JBF", "WMF", "RF-WF", "TV", "PD")


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


def default_grids(model: CorrectionModel | FCNCorrectionModel, *, quick: bool = False
                  ) -> dict[str, GridSpec]:
    """The grids of every baseline.

    ``quick=False``: each baseline's own ``param_grid`` plus ``fit_param_grid`` with its default
    constructor (the full search; RFD alone refits a 30-tree forest per ``max_depth``, minutes).
    ``quick=True``: a few values around the full grids' usual winners and smaller forests and
    dictionary, for the demo (about a minute of tuning on the small simulated dataset).
    RFD uses the model's patch encoding (the same features as F); an fcn model has none, so
    there RFD keeps its own default encoding.
    """
    enc = {"encoding": model.encoding} if isinstance(model, CorrectionModel) else {}
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

