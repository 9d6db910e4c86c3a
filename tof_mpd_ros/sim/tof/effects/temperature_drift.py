"""``temperature_drift``: the camera warms up and its range offset creeps.

    e(n) = max_mm · (1 − exp(−n / tau_frames))      [mm], n = frame index

The same offset for every pixel of frame n; a per-frame constant, so frames late in a recording
read farther than early ones.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..context import RenderContext
from ..effect import Effect, param


def drift_mm(frame_index: int, max_mm: float, tau_frames: float) -> float:
    """Range offset in mm of frame ``frame_index``."""
    return max_mm * (1.0 - math.exp(-max(frame_index, 0) / tau_frames))


@dataclass(frozen=True)
class TemperatureDriftParams:
    """Parameters of :class:`TemperatureDrift`."""

    max_mm: float = param(5.0, -20.0, 20.0, "mm", "offset once warm")
    tau_frames: float = param(100.0, 5.0, 2000.0, "frames", "warm-up time constant")


class TemperatureDrift(Effect):
    name = "temperature_drift"
    stage = "range"
    summary = "range offset growing with frame index (warm-up)"
    Params = TemperatureDriftParams

    def apply(self, x: np.ndarray, params: TemperatureDriftParams,
              ctx: RenderContext) -> np.ndarray:
        return x + drift_mm(ctx.frame_index, float(params.max_mm), float(params.tau_frames))
