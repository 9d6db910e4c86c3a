"""The paper's evaluation of the method on test frames: accuracy of each stage and G's edges.

Stages (the paper's component analysis, Fig. 8): ``raw`` ToF range, ``calibrated`` (intrinsic
calibration), ``F`` (range-recovery net alone), ``geodesic+G`` (geodesic filtering with G's
edges, without F) and ``full`` (calibration → F → G → geodesic). Edge detection (Fig. 10): G's
non-maximum-suppressed strength against OpenCV Canny on the raw range, both scored against
Canny on the reference (the ground-truth boundaries).

A model of the ``"fcn"`` kind (:mod:`~tof_mpd_ros.correction.fcn`) has no F, G or geodesic
step to take apart: its stages are ``raw``, ``calibrated`` and ``fcn`` (its full output), it has
no edge curves and no G operating point (not measured, so absent rather than made up), and its
predicted σ is checked instead: the k-σ coverage (:class:`~.metrics.SigmaCoverage`) of
``calibrated + correction`` over every pixel it predicts.
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
from ..correction.fcn import FCNCorrectionModel
from ..correction.networks import boundary_scores
from ..correction.pipeline import (
    CorrectionModel,
    CorrectionResult,
    correct,
    require_patch_kind,
)
from ..frame import ToFFrame
from .diagnosis import RegionTally, edge_distance, edges_by_orientation
from .metrics import (
    DEFAULT_THRESHOLDS_MM,
    EdgePRCurve,
    FrameAccumulator,
    FrameEvaluation,
    SigmaCoverage,
    boundary_region,
    edge_precision_recall,
)

STAGES = ("raw", "calibrated", "F", "geodesic+G", "full")
FCN_STAGES = ("raw", "calibrated", "fcn")
#: the stages of each model kind, in report order; the last is the kind's full output
STAGES_BY_KIND = {"patch": STAGES, "fcn": FCN_STAGES}
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
        kind: the model's kind, ``"patch"`` or ``"fcn"`` (:data:`STAGES_BY_KIND` its stages;
            an fcn model has empty ``edges`` and ``g_operating_point``).
        coverage: the fcn kind's k-σ coverage (:meth:`.metrics.SigmaCoverage.result`); empty
            for the patch kind, which predicts no σ.
    """

    stages: dict[str, FrameEvaluation]
    edges: dict[str, EdgePRCurve]
    seconds_per_frame: float
    n_frames: int
    examples: list[dict[str, np.ndarray]] = field(default_factory=list)
    regions: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)
    g_operating_point: dict[str, Any] = field(default_factory=dict)
    kind: str = "patch"
    coverage: dict[str, Any] = field(default_factory=dict)

    @property
    def final_stage(self) -> str:
        """The stage that is the model's full output (``full`` or ``fcn``)."""
        return STAGES_BY_KIND[self.kind][-1]

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
        full5 = self.stages[self.final_stage].whole.at(5.0)
        return {"model_kind": self.kind, "final_stage": self.final_stage,
                "n_frames": self.n_frames, "seconds_per_frame": self.seconds_per_frame,
                "summary_5mm": self.summary(5.0),
                "relative_improvement_5mm": (full5 - raw5) / raw5 if raw5 > 0 else None,
                "stages": {k: v.to_dict() for k, v in self.stages.items()},
                "edges": {k: v.to_dict() for k, v in self.edges.items()},
                "regions": self.regions, "g_operating_point": self.g_operating_point,
                "sigma_coverage": self.coverage or None}


def g_probabilities(model: CorrectionModel, calibrated_mm: np.ndarray,
                    amplitude: np.ndarray) -> np.ndarray:
    """G's four heads' edge probabilities of one frame.

    Args:
        calibrated_mm: (H, W) float32 calibrated radial range in mm, NaN = invalid.
        amplitude: (H, W) float32 amplitude.

    Returns:
        (4, H, W) float32 probability per orientation group, 0 on invalid pixels.

    Raises:
        InputError: ``model`` is not of the patch kind (it has no G).
    """
    require_patch_kind(model, "G's edge probabilities")
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


@dataclass
class FrameStages:
    """One frame through every stage of the method, with its ground truth.

    Attributes:
        stages: stage (the kind's :data:`STAGES_BY_KIND` order) -> (H, W) float32 range in mm,
            NaN = no estimate.
        full: the full correction (:class:`~tof_mpd_ros.correction.pipeline.CorrectionResult`:
            calibrated range, R_F, output and G's edge map, or the fcn kind's σ).
        seconds: wall time of the full correction, s.
        gt_edges: (H, W) bool ground-truth edges of the reference.
        boundary: (H, W) bool boundary region (within 5 px of ``gt_edges``).
        edge_distance: (H, W) float32 distance to the nearest ground-truth edge, px (inf: none).
    """

    stages: dict[str, np.ndarray]
    full: CorrectionResult
    seconds: float
    gt_edges: np.ndarray
    boundary: np.ndarray
    edge_distance: np.ndarray


class ComponentTally:
    """The package's one per-frame evaluation of the method's stages: ``add`` runs every stage
    on a frame and pools the paper's metrics, ``result`` gives the
    :class:`ComponentEvaluation`. ``tof-mpd evaluate`` (:func:`evaluate_model`) and the
    benchmark (:func:`~tof_mpd_ros.evaluation.benchmark.run_benchmark`, which adds the other
    methods on the same frames) both use it.

    Args:
        model: the correction model, either kind (:data:`STAGES_BY_KIND` says what is run).
        thresholds: accuracy-curve thresholds in mm.
        diagnostics: also pool the stages' accuracy by distance to the edges and G's operating
            point (``regions`` and ``g_operating_point`` of the result; empty when False).
        precision: the networks' arithmetic in every stage (``pipeline.PRECISIONS``).
    """

    def __init__(self, model: CorrectionModel | FCNCorrectionModel,
                 thresholds: tuple[float, ...] = DEFAULT_THRESHOLDS_MM, *,
                 diagnostics: bool = True, precision: str = "float32") -> None:
        self.model = model
        self.precision = precision
        self.kind = model.kind
        self.stage_names = STAGES_BY_KIND[self.kind]
        self.diagnostics = diagnostics
        self._stages = {s: FrameAccumulator(thresholds) for s in self.stage_names}
        self._regions = RegionTally(5.0)
        self._coverage = SigmaCoverage(max_sigma_mm=getattr(model, "max_sigma_mm", None))
        self._seconds: list[float] = []
        # per frame, for the edge curves (patch kind): G's NMS strength, Canny's, the
        # reference's edges and valid pixels; with diagnostics G's binary map, its winning
        # head and the edges' groups
        self._g_scores: list[np.ndarray] = []
        self._canny: list[np.ndarray] = []
        self._gts: list[np.ndarray] = []
        self._valids: list[np.ndarray] = []
        self._g_maps: list[np.ndarray] = []
        self._g_groups: list[np.ndarray] = []
        self._gt_groups: list[np.ndarray] = []

    def _stages_of(self, range_mm: np.ndarray, amplitude: np.ndarray,
                   full: CorrectionResult) -> dict[str, np.ndarray]:
        """Stage -> (H, W) range of one frame (the patch kind runs G alone once more)."""
        if self.kind == "fcn":
            return {"raw": range_mm, "calibrated": full.calibrated_mm, "fcn": full.range_mm}
        g_only = correct(self.model, range_mm, amplitude, use_range_net=False,
                         precision=self.precision)
        return {"raw": range_mm, "calibrated": full.calibrated_mm, "F": full.range_f_mm,
                "geodesic+G": g_only.range_mm, "full": full.range_mm}

    def add(self, range_mm: np.ndarray, amplitude: np.ndarray,
            reference_mm: np.ndarray) -> FrameStages:
        """Run every stage on one frame and pool it.

        Args:
            range_mm: (H, W) float32 raw radial range in mm (the model's crop), NaN = invalid.
            amplitude: (H, W) float32 raw amplitude.
            reference_mm: (H, W) float32 reference range in mm, NaN = missing.
        """
        start = time.perf_counter()
        full = correct(self.model, range_mm, amplitude, precision=self.precision)
        seconds = time.perf_counter() - start
        stages = self._stages_of(range_mm, amplitude, full)
        gt, gt_group = ground_truth_edges(reference_mm)
        mask = boundary_region(reference_mm, edges=gt)
        distance = edge_distance(gt)
        for name in self.stage_names:
            self._stages[name].add(stages[name], reference_mm, mask)
        self._seconds.append(seconds)
        if self.diagnostics:
            self._regions.add(stages, reference_mm, distance)
        if full.sigma_mm is not None:
            self._coverage.add(full.range_f_mm, full.sigma_mm, reference_mm)
        if self.kind == "patch":
            self._add_edges(range_mm, amplitude, reference_mm, full, gt, gt_group)
        return FrameStages(stages, full, seconds, gt, mask, distance)

    def _add_edges(self, range_mm: np.ndarray, amplitude: np.ndarray,
                   reference_mm: np.ndarray, full: CorrectionResult, gt: np.ndarray,
                   gt_group: np.ndarray) -> None:
        """Pool G's and Canny's edges of one frame (patch kind)."""
        probs = g_probabilities(self.model, full.calibrated_mm, amplitude)
        self._g_scores.append(edge_map_from_responses(probs)[1])
        self._canny.append(canny_score_map(range_mm, highs=np.array(CANNY_HIGHS_MM)))
        self._gts.append(gt)
        self._valids.append(np.isfinite(reference_mm))
        if self.diagnostics:
            self._g_maps.append(full.edges)
            self._g_groups.append(np.argmax(probs, axis=0))
            self._gt_groups.append(gt_group)

    def result(self, examples: list[dict[str, np.ndarray]] | None = None
               ) -> ComponentEvaluation:
        """The pooled evaluation of the frames added so far (``examples``: arrays to plot)."""
        edges = {}
        if self.kind == "patch":
            edges = {"G": edge_precision_recall(self._g_scores, self._gts, G_THRESHOLDS,
                                                valid=self._valids),
                     "Canny (raw ToF)": edge_precision_recall(
                         self._canny, self._gts, CANNY_HIGHS_MM, valid=self._valids)}
        median = float(np.median(self._seconds)) if self._seconds else float("nan")
        return ComponentEvaluation({s: acc.result() for s, acc in self._stages.items()}, edges,
                                   median, len(self._seconds), examples or [],
                                   self._regions.result() if self.diagnostics else {},
                                   self._operating_point(), self.kind,
                                   self._coverage.result() if self.kind == "fcn" else {})

    def _operating_point(self) -> dict[str, Any]:
        """Precision / recall of G's binary edge map (2 px), overall and per orientation."""
        if not self._g_maps:
            return {}
        point = edge_precision_recall([m.astype(np.float32) for m in self._g_maps], self._gts,
                                      [0.5], valid=self._valids)
        by_orientation = edges_by_orientation(
            [m & v for m, v in zip(self._g_maps, self._valids, strict=True)], self._g_groups,
            self._gts, self._gt_groups)
        return {"precision": float(point.precision[0]), "recall": float(point.recall[0]),
                "by_orientation": by_orientation}


def evaluate_model(model: CorrectionModel | FCNCorrectionModel, frames: Iterable[ToFFrame], *,
                   thresholds: tuple[float, ...] = DEFAULT_THRESHOLDS_MM,
                   n_examples: int = 3, precision: str = "float32") -> ComponentEvaluation:
    """Run every stage on every frame with a reference and pool the paper's metrics
    (:class:`ComponentTally`; either kind of model, the networks in ``precision``); the first
    ``n_examples`` frames are kept for plots (with ``edges_g`` for the patch kind, ``sigma_mm``
    for the fcn kind).

    Frames without a reference are skipped (nothing to score against).
    """
    tally = ComponentTally(model, thresholds, precision=precision)
    examples: list[dict[str, np.ndarray]] = []
    for frame in frames:
        if frame.reference_mm is None:
            continue
        out = tally.add(frame.range_mm, frame.amplitude, frame.reference_mm)
        if len(examples) < n_examples:
            extra = ({"sigma_mm": out.full.sigma_mm} if out.full.sigma_mm is not None
                     else {"edges_g": out.full.edges})
            examples.append({"reference": frame.reference_mm, **out.stages,
                             "amplitude": frame.amplitude, **extra})
    return tally.result(examples)


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
