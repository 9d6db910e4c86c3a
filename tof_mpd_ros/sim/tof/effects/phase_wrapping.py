"""``phase_wrapping``: range is the phase of the phasor, so it wraps at c / (2f).

Enabled, the measured range is ``angle(Z) / (4π f / c)`` in [0, c/2f). Disabled, an ideal unwrapping
oracle adds the whole number of ambiguity intervals that brings it nearest the pixel's true
range. At the default 30 MHz (c/2f ≈ 4997 mm) nothing in the 150–450 mm workspace wraps, so both
agree there; the effect matters when a camera runs at higher frequency or sees far surfaces.
"""

from __future__ import annotations

import numpy as np

from ..context import RenderContext
from ..effect import Effect, NoParams
from ..phasor import phasor_to_range, unwrap_to_guide


class PhaseWrapping(Effect):
    name = "phase_wrapping"
    stage = "readout"
    nominal = True
    summary = "range from the phasor's angle wraps at c/(2f)"

    def apply(self, x: np.ndarray, params: NoParams, ctx: RenderContext) -> np.ndarray:
        return phasor_to_range(x, ctx.mod_freq_hz)

    def bypass(self, x: np.ndarray, ctx: RenderContext) -> np.ndarray:
        """The readout when the effect is off: range unwrapped next to the true range."""
        guide = ctx.true_range_mm if ctx.true_range_mm is not None else np.full(x.shape, np.nan)
        return unwrap_to_guide(phasor_to_range(x, ctx.mod_freq_hz), guide, ctx.mod_freq_hz)
