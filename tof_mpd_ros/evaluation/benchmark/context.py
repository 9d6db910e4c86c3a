"""Where and how a benchmark ran: the machine (for the absolute timings) and the settings."""

from __future__ import annotations

import os
import platform
from typing import Any

import torch

from ...correction.fcn import FCNCorrectionModel
from ...correction.pipeline import CorrectionModel
from ...machine import cpu_model
from .config import RANK_THRESHOLD_MM, BenchmarkConfig

TIMING_NOTE = ("median wall time per frame on this machine, calibration included for every "
               "method after raw; the machine may be shared")


def machine_info() -> dict[str, Any]:
    """The machine the run was on (for the absolute timings)."""
    return {"cpu": cpu_model(), "cpu_count": os.cpu_count(),
            "torch_threads": torch.get_num_threads(),
            "python": platform.python_version(), "platform": platform.platform()}


def run_info(model: CorrectionModel | FCNCorrectionModel, config: BenchmarkConfig
             ) -> dict[str, Any]:
    """Provenance of a run: the machine, the settings, the model's kind and crop."""
    return {"machine": machine_info(), "quick": config.quick,
            "val_fraction": config.val_fraction, "max_val_frames": config.max_val_frames,
            "thresholds_mm": list(config.thresholds), "rank_threshold_mm": RANK_THRESHOLD_MM,
            "model_kind": model.kind, "model_shape": list(model.shape), "timing_note": TIMING_NOTE}
