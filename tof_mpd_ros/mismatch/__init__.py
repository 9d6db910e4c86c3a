"""Sim-vs-real mismatch tool (docs/mismatch.md): locate where a real recording departs from the
simulated cell, name the physics the simulator left out, fit it, and show the fit improve.

* :func:`analyse` — frames in, :class:`Analysis` out (ranking, selected effects, fitted config,
  held-out residuals before/after, localisation);
* :func:`write_report` — ``report.json``, ``fitted_config.json``, PNGs and ``index.html``;
* :func:`run_benchmark` — concealed-effect benchmark (top-1, false alarms, parameter error,
  RMSE reduction);
* :func:`azure_kinect_frame` — the real Azure Kinect frame with a plane-fit reference.

Pure numpy/scipy; never imports rclpy.
"""

from __future__ import annotations

from .analysis import Analysis, analyse
from .benchmark import run_benchmark
from .data import load_frames
from .fit import CANDIDATES
from .report import write_report

__all__ = ["CANDIDATES", "Analysis", "analyse", "load_frames", "run_benchmark", "write_report"]
