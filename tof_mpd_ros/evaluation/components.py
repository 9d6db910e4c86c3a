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
from typing import Any

import numpy as np
import torch

from ..correction.edges import canny_score_map, edge_map_from_responses, ground_truth_edges
from ..correction.encoding import encode_frame
from ..correction.networks import boundary_scores
from ..correction.pipeline import CorrectionModel, correct
from ..frame import ToFFrame
from .diagnosis import RegionTally, edge_distance, edges_by_orientation
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
        regions: per region by distance to the ground-truth edges (:data:`REGIONS`), per
            stage: fraction within 5 mm, MAE (mm) and pixel count — what F and the geodesic
            step do at the edges, near them and in the interior.
        g_operating_point: precision / recall (2 px tolerance) of the binary edge map the
            full pipeline uses (G's thresholds and hysteresis), not a sweep; and
            ``by_orientation`` (:func:`.diagnosis.edges_by_orientation`): the same per
            orientation group of the edge normal, with how often G's winning head names the
            nearest reference edge's group.
    """

    stages: dict[str, FrameEvaluation]
    edges: dict[str, EdgePRCurve]
    seconds_per_frame: float
    n_frames: int
    examples: list[dict[str, np.ndarray]] = field(default_factory=list)
    regions: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)
    g_operating_point: dict[str, Any] = field(default_factory=dict)

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
                "edges": {k: v.to_dict() for k, v in self.edges.items()},
                "regions": self.regions, "g_operating_point": self.g_operating_point}


def g_probabilities(model: CorrectionModel, calibrated_mm: np.ndarray,
                    amplitude: np.ndarray) -> np.ndarray:
    """G's four heads' edge probabilities of one frame.

    Args:
        calibrated_mm: (H, W) float32 calibrated radial range in mm, NaN = invalid.
        amplitude: (H, W) float32 amplitude.

    Returns:
        (4, H, W) float32 probability per orientation group, 0 on invalid pixels.
    """
    features, valid = encode_frame(calibrated_mm, amplitude, model.encoding, boundary_only=True)
    with torch.no_grad():
        probs = boundary_scores(features, model.boundary_nets).numpy()
    h, w = calibrated_mm.shape
    return np.where(valid[0].numpy(), probs.T.reshape(4, h, w), 0.0).astype(np.float32)


def g_edge_strength(model: CorrectionModel, calibrated_mm: np.ndarray,
                    amplitude: np.ndarray) -> np.ndarray:
    """G's non-maximum-suppressed edge strength of one frame (for precision/recall sweeps):
    (H, W) float32 edge probability where a ridge survives NMS, 0 elsewhere (arguments as
    :func:`g_probabilities`)."""
    return edge_map_from_responses(g_probabilities(model, calibrated_mm, amplitude))[1]


def evaluate_model(model: CorrectionModel, frames: Iterable[ToFFrame], *,
                   thresholds: tuple[float, ...] = DEFAULT_THRESHOLDS_MM,
                   n_examples: int = 3) -> ComponentEvaluation:
    """Run every stage on every frame with a reference and pool the paper's metrics.

    Frames without a reference are skipped (nothing to score against).
    """
    estimates: dict[str, list[np.ndarray]] = {s: [] for s in STAGES}
    references, masks, g_scores, canny_scores, gts, valids = [], [], [], [], [], []
    g_maps: list[np.ndarray] = []
    g_groups: list[np.ndarray] = []
    gt_groups: list[np.ndarray] = []
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
        gt, gt_group = ground_truth_edges(frame.reference_mm)
        references.append(frame.reference_mm)
        masks.append(boundary_region(frame.reference_mm, edges=gt))
        gts.append(gt)
        g_maps.append(full.edges)
        gt_groups.append(gt_group)
        valids.append(np.isfinite(frame.reference_mm))
        probs = g_probabilities(model, full.calibrated_mm, frame.amplitude)
        g_groups.append(np.argmax(probs, axis=0))
        g_scores.append(edge_map_from_responses(probs)[1])
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
    regions = region_accuracy(estimates, references, gts)
    point = edge_precision_recall([m.astype(np.float32) for m in g_maps], gts, [0.5],
                                  valid=valids) if g_maps else None
    operating = {} if point is None else {
        "precision": float(point.precision[0]), "recall": float(point.recall[0]),
        "by_orientation": edges_by_orientation(
            [m & v for m, v in zip(g_maps, valids, strict=True)], g_groups, gts, gt_groups)}
    return ComponentEvaluation(stages, edges, median, len(references), examples, regions,
                               operating)


def region_accuracy(estimates: dict[str, list[np.ndarray]], references: list[np.ndarray],
                    gt_edges: list[np.ndarray], threshold_mm: float = 5.0
                    ) -> dict[str, dict[str, dict[str, float]]]:
    """Per region (:data:`REGIONS`) and stage: fraction of the scored pixels within
    ``threshold_mm``, MAE (mm) and the number of pixels.

    Args:
        estimates: stage -> N (H, W) float range estimates, mm (NaN = no estimate: an error).
        references: N (H, W) float references, mm (NaN = not scored).
        gt_edges: N (H, W) bool ground-truth edges.
    """
    tally = RegionTally(threshold_mm)
    for i, (ref, gt) in enumerate(zip(references, gt_edges, strict=True)):
        tally.add({stage: est[i] for stage, est in estimates.items()}, ref, edge_distance(gt))
    return tally.result()
