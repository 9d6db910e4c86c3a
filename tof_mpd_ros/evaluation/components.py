"""The paper's evaluation of the method on test frames: accuracy of each stage and G's edges.

Stages (the paper's component analysis, Fig. 8): ``raw`` ToF range, ``calibrated`` (intrinsic
calibration), ``F`` (range-recovery net alone), ``geodesic+G`` (geodesic filtering with G's
edges, without F) and ``full`` (calibration → F → G → geodesic). Edge detection (Fig. 10): G's
non-maximum-suppressed strength against OpenCV Canny on the raw range, both scored against
Canny on the reference (the ground-truth boundaries).
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
import torch

from ..correction.edges import canny_score_map, edge_map_from_responses, ground_truth_edges
from ..correction.encoding import encode_frame
from ..correction.networks import boundary_scores
from ..correction.pipeline import CorrectionModel, correct
from ..frame import ToFFrame
from .metrics import (
    DEFAULT_THRESHOLDS_MM,
    EdgePRCurve,
    FrameEvaluation,
    boundary_region,
    edge_precision_recall,
    evaluate_frames,
)

STAGES = ("raw", "calibrated", "F", "geodesic+G", "full")
G_THRESHOLDS = tuple(np.round(np.linspace(0.05, 0.95, 19), 3))
CANNY_HIGHS_MM = tuple(float(t) for t in np.geomspace(2.0, 80.0, 19))


@dataclass
class ComponentEvaluation:
    """Everything the ``evaluate`` command reports.

    Attributes:
        stages: accuracy curves (whole image and boundary region) per stage.
        edges: precision/recall curves of ``G`` and ``Canny`` (raw ToF).
        seconds_per_frame: median wall time of the full correction per frame.
        examples: a few frames' arrays for plots (reference, raw and each stage).
    """

    stages: dict[str, FrameEvaluation]
    edges: dict[str, EdgePRCurve]
    seconds_per_frame: float
    n_frames: int
    examples: list[dict[str, np.ndarray]] = field(default_factory=list)

    def summary(self, threshold_mm: float = 5.0) -> dict[str, dict[str, float]]:
        """Per stage: fraction within ``threshold_mm`` (whole, boundary), MAE, RMSE."""
        out = {}
        for name, ev in self.stages.items():
            out[name] = {"within_mm": threshold_mm, "whole": ev.whole.at(threshold_mm),
                         "boundary": ev.boundary.at(threshold_mm),
                         "mae_mm": ev.whole.mae_mm, "rmse_mm": ev.whole.rmse_mm}
        return out

    def to_dict(self) -> dict:
        raw5 = self.stages["raw"].whole.at(5.0)
        full5 = self.stages["full"].whole.at(5.0)
        return {"n_frames": self.n_frames, "seconds_per_frame": self.seconds_per_frame,
                "summary_5mm": self.summary(5.0),
                "relative_improvement_5mm": (full5 - raw5) / raw5 if raw5 > 0 else None,
                "stages": {k: v.to_dict() for k, v in self.stages.items()},
                "edges": {k: v.to_dict() for k, v in self.edges.items()}}


def g_edge_strength(model: CorrectionModel, calibrated_mm: np.ndarray,
                    amplitude: np.ndarray) -> np.ndarray:
    """G's non-maximum-suppressed edge strength of one frame (for precision/recall sweeps).

    Args:
        calibrated_mm: (H, W) float32 calibrated radial range in mm, NaN = invalid.
        amplitude: (H, W) float32 amplitude.

    Returns:
        (H, W) float32 edge probability where a ridge survives NMS, 0 elsewhere.
    """
    features, valid = encode_frame(calibrated_mm, amplitude, model.encoding, boundary_only=True)
    with torch.no_grad():
        probs = boundary_scores(features, model.boundary_nets).numpy()
    h, w = calibrated_mm.shape
    scores = np.where(valid[0].numpy(), probs.T.reshape(4, h, w), 0.0).astype(np.float32)
    return edge_map_from_responses(scores)[1]


def evaluate_model(model: CorrectionModel, frames: Iterable[ToFFrame], *,
                   thresholds: tuple[float, ...] = DEFAULT_THRESHOLDS_MM,
                   n_examples: int = 3) -> ComponentEvaluation:
    """Run every stage on every frame with a reference and pool the paper's metrics.

    Frames without a reference are skipped (nothing to score against).
    """
    estimates: dict[str, list[np.ndarray]] = {s: [] for s in STAGES}
    references, masks, g_scores, canny_scores, gts, valids = [], [], [], [], [], []
    examples: list[dict[str, np.ndarray]] = []
    seconds: list[float] = []
    for frame in frames:
        if frame.reference_mm is None:
            continue
        start = time.perf_counter()
        full = correct(model, frame.range_mm, frame.amplitude)
        seconds.append(time.perf_counter() - start)
        g_only = correct(model, frame.range_mm, frame.amplitude, use_range_net=False)
        stage = {"raw": frame.range_mm, "calibrated": full.calibrated_mm, "F": full.range_f_mm,
                 "geodesic+G": g_only.range_mm, "full": full.range_mm}
        for name in STAGES:
            estimates[name].append(stage[name])
        gt, _ = ground_truth_edges(frame.reference_mm)
        references.append(frame.reference_mm)
        masks.append(boundary_region(frame.reference_mm, edges=gt))
        gts.append(gt)
        valids.append(np.isfinite(frame.reference_mm))
        g_scores.append(g_edge_strength(model, full.calibrated_mm, frame.amplitude))
        canny_scores.append(canny_score_map(frame.range_mm, highs=np.array(CANNY_HIGHS_MM)))
        if len(examples) < n_examples:
            examples.append({"reference": frame.reference_mm, **stage,
                             "amplitude": frame.amplitude, "edges_g": full.edges})
    stages = {name: evaluate_frames(est, references, thresholds, boundary_masks=masks)
              for name, est in estimates.items()}
    edges = {"G": edge_precision_recall(g_scores, gts, G_THRESHOLDS, valid=valids),
             "Canny (raw ToF)": edge_precision_recall(canny_scores, gts, CANNY_HIGHS_MM,
                                                      valid=valids)}
    median = float(np.median(seconds)) if seconds else float("nan")
    return ComponentEvaluation(stages, edges, median, len(references), examples)
