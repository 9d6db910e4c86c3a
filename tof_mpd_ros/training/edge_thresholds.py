"""G's hysteresis thresholds chosen on validation frames, for the geodesic step they feed.

The paper fixes the thresholds that turn G's four probabilities into the binary edge map the
geodesic filter must not cross. They do not transfer: on a camera the product was not built on,
G fired at precision 0.29 for recall 0.99 and G + geodesic made the boundary region *worse*
than F alone (issue 16). The thresholds exist for the final range, so they are chosen by it:
for every (low, high) pair of a grid, the full pipeline's range on the held-out frames, scored
as the paper scores it (fraction within 5 mm), first in the boundary region, then on the whole
image. F alone (no geodesic step) is scored beside them, so the report says whether the step
helps on this data at all.

Only the patch kind has G and a geodesic step: a model of the fcn kind is refused
(:class:`~tof_mpd_ros.errors.InputError`), it has no thresholds to choose.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..correction import edges as edge_module
from ..correction import geodesic
from ..correction.pipeline import CorrectionModel, correct, require_patch_kind
from ..evaluation.components import g_probabilities
from ..evaluation.metrics import FrameAccumulator, boundary_region
from ..frame import ToFFrame

#: (low, high) pairs tried: lows 0.1..0.7, highs above them up to 0.95
THRESHOLD_GRID = tuple((lo, hi) for lo in (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7)
                       for hi in (0.3, 0.45, 0.6, 0.75, 0.9, 0.95) if hi > lo)
WITHIN_MM = 5.0


@dataclass(frozen=True)
class ThresholdChoice:
    """The chosen thresholds and what every candidate scored on the validation frames.

    Attributes:
        low, high: the chosen hysteresis thresholds.
        table: per candidate (low, high, boundary fraction within 5 mm, whole fraction).
        f_alone: (boundary, whole) fractions within 5 mm of F alone (no geodesic step).
        before: (low, high, boundary, whole) of the model's thresholds before the choice (the
            paper's 0.3 / 0.6 for a fresh model).
    """

    low: float
    high: float
    table: tuple[tuple[float, float, float, float], ...]
    f_alone: tuple[float, float]
    before: tuple[float, float, float, float]

    def as_dict(self) -> dict:
        return {"low": self.low, "high": self.high, "f_alone": list(self.f_alone),
                "before": list(self.before), "candidates": [list(row) for row in self.table]}


def _frame_inputs(model: CorrectionModel, frame: ToFFrame
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(R_F (H, W) float32 mm, G probabilities (4, H, W) float32, reference (H, W) mm,
    boundary region (H, W) bool) of one validation frame."""
    result = correct(model, frame.range_mm, frame.amplitude, use_boundary=False)
    scores = g_probabilities(model, result.calibrated_mm, frame.amplitude)
    reference = np.asarray(frame.reference_mm, np.float32)
    return result.range_f_mm, scores, reference, boundary_region(reference)


def _score(estimates: Sequence[np.ndarray], inputs: Sequence[tuple]) -> tuple[float, float]:
    """(boundary, whole) fractions within 5 mm, pooled over the frames."""
    acc = FrameAccumulator((WITHIN_MM,))
    for est, (_, _, ref, region) in zip(estimates, inputs, strict=True):
        acc.add(est, ref, region)
    ev = acc.result()
    return ev.boundary.accuracy[0], ev.whole.accuracy[0]


def _filtered(model: CorrectionModel, inputs: Sequence[tuple], low: float, high: float
              ) -> list[np.ndarray]:
    g = model.geodesic
    out = []
    for range_f, scores, _, _ in inputs:
        edge_map, _ = edge_module.edge_map_from_responses(scores, low=low, high=high)
        out.append(np.asarray(geodesic.geodesic_filter(range_f, edge_map, k=g.k, sigma=g.sigma,
                                                        step=g.step), np.float32))
    return out


def choose_edge_thresholds(model: CorrectionModel, frames: Sequence[ToFFrame],
                           grid: Sequence[tuple[float, float]] = THRESHOLD_GRID
                           ) -> ThresholdChoice | None:
    """The (low, high) pair whose full-pipeline range is most often within 5 mm in the
    boundary region of ``frames`` (ties: on the whole image, then the paper's default).

    Args:
        model: the trained model (its calibration, F and G are used as they are).
        frames: held-out frames with references.
        grid: candidate (low, high) pairs, low <= high.

    Returns:
        The choice with every candidate's scores, or None without usable frames.

    Raises:
        InputError: ``model`` is not of the patch kind (no G, no geodesic step).
    """
    require_patch_kind(model, "choosing G's edge thresholds")
    usable = [f for f in frames if f.reference_mm is not None]
    if not usable:
        return None
    inputs = [_frame_inputs(model, f) for f in usable]
    f_alone = _score([i[0] for i in inputs], inputs)
    pairs = list(dict.fromkeys([(model.geodesic.edge_low, model.geodesic.edge_high),
                                *grid]))
    table = [(lo, hi, *_score(_filtered(model, inputs, lo, hi), inputs)) for lo, hi in pairs]
    best = max(table, key=lambda row: (row[2], row[3]))
    return ThresholdChoice(best[0], best[1], tuple(table), f_alone, table[0])


def with_thresholds(model: CorrectionModel, choice: ThresholdChoice) -> CorrectionModel:
    """``model`` whose geodesic step uses the chosen thresholds.

    Raises:
        InputError: ``model`` is not of the patch kind (it has no edge thresholds).
    """
    require_patch_kind(model, "setting G's edge thresholds")
    model.geodesic = replace(model.geodesic, edge_low=choice.low, edge_high=choice.high)
    return model
