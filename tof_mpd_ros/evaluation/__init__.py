"""Evaluation as in the paper: accuracy-vs-threshold curves (whole image and boundary region),
MAE/RMSE, edge precision/recall with max F1, the k-σ coverage of a predicted σ, and their
figures.

Pure numpy/OpenCV/matplotlib (Agg); never imports rclpy. :mod:`.plots` is imported on demand so
that metrics do not pull in matplotlib.
"""

from __future__ import annotations

from .metrics import (
    BOUNDARY_RADIUS_PX,
    DEFAULT_THRESHOLDS_MM,
    AccuracyCurve,
    EdgePRCurve,
    FrameAccumulator,
    FrameEvaluation,
    SigmaCoverage,
    accuracy_curve,
    boundary_region,
    edge_precision_recall,
    evaluate_frames,
)

__all__ = [
    "BOUNDARY_RADIUS_PX", "DEFAULT_THRESHOLDS_MM", "AccuracyCurve", "EdgePRCurve",
    "FrameAccumulator", "FrameEvaluation", "SigmaCoverage", "accuracy_curve", "boundary_region",
    "edge_precision_recall", "evaluate_frames",
]
