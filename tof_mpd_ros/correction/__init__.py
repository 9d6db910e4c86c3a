"""Multipath-distortion correction (paper §III): patch encoding, networks F and G, edge map,
geodesic filtering, the weights file and the full pipeline (which first applies the per-pixel
calibration of :mod:`tof_mpd_ros.calibration`); and the second model kind, the
fully-convolutional network with a predicted σ (:mod:`.fcn`).

Pure numpy/torch; never imports rclpy. The ROS node and the CLI call :func:`correct`.
"""

from __future__ import annotations

from .encoding import EncodingConfig, encode_frame
from .fcn import FCNArchitecture, FCNCorrectionModel
from .networks import BoundaryNets, RangeRecoveryNet, boundary_scores, recover_range
from .pipeline import CorrectionModel, CorrectionResult, GeodesicParams, correct
from .weights import load_weights, save_weights

__all__ = [
    "BoundaryNets", "CorrectionModel", "CorrectionResult", "EncodingConfig", "FCNArchitecture",
    "FCNCorrectionModel", "GeodesicParams",
    "RangeRecoveryNet", "boundary_scores", "correct", "encode_frame", "load_weights",
    "recover_range", "save_weights",
]
