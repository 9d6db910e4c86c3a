"""``wiggling``: cyclic range error from the non-sinusoidal modulation (odd harmonics).

With square-ish modulation the 3rd and 5th harmonics alias into an error periodic in the phase
φ = 4π f r / c with period 2π/4 (and 2π/8 for the next term):

    e(r) = a1 · sin(4φ + p1) + a2 · sin(8φ + p2)     [mm]

At 30 MHz, 4φ only sweeps about 1.5 rad over the 150–450 mm workspace, so most of the error is
absorbed by the per-pixel linear calibration; the residual is a slow bow (see docs/physics.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..context import RenderContext
from ..effect import Effect, param
from ..phasor import phase_per_mm


def wiggle_mm(range_mm: np.ndarray, mod_freq_hz: float, a1: float, p1: float, a2: float,
              p2: float) -> np.ndarray:
    """Wiggling error in mm at measured range ``range_mm`` (any shape, mm)."""
    phi = phase_per_mm(mod_freq_hz) * range_mm
    return a1 * np.sin(4.0 * phi + p1) + a2 * np.sin(8.0 * phi + p2)


@dataclass(frozen=True)
class WigglingParams:
    """Parameters of :class:`Wiggling`."""

    a1_mm: float = param(3.0, 0.0, 20.0, "mm", "amplitude of the 4φ term")
    p1_rad: float = param(0.5, -np.pi, np.pi, "rad", "phase of the 4φ term")
    a2_mm: float = param(1.0, 0.0, 10.0, "mm", "amplitude of the 8φ term")
    p2_rad: float = param(1.0, -np.pi, np.pi, "rad", "phase of the 8φ term")


class Wiggling(Effect):
    name = "wiggling"
    stage = "range"
    nominal = True
    summary = "cyclic error in the phase (harmonics 4φ, 8φ), a few mm"
    Params = WigglingParams

    def apply(self, x: np.ndarray, params: WigglingParams,
              ctx: RenderContext) -> np.ndarray:
        return x + wiggle_mm(x, ctx.mod_freq_hz, float(params.a1_mm), float(params.p1_rad),
                             float(params.a2_mm), float(params.p2_rad))
