"""``amplitude_bias``: range depends on how much light the pixel got (intensity-related error).

    e(a) = bias_mm · ((a_ref / a)^exponent − 1)      [mm]

zero at ``ref_amplitude``, growing for dim pixels (dark or distant surfaces read farther). Over
the workspace's amplitude range a per-pixel linear term in a removes most of it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..context import RenderContext
from ..effect import Effect, param


@dataclass(frozen=True)
class AmplitudeBiasParams:
    """Parameters of :class:`AmplitudeBias`."""

    bias_mm: float = param(2.0, -20.0, 20.0, "mm", "scale of the bias")
    ref_amplitude: float = param(300.0, 10.0, 2000.0, "amplitude", "amplitude with no bias",
                                 fit=False)
    exponent: float = param(0.5, 0.1, 2.0, "1", "how fast the bias grows as a falls")


class AmplitudeBias(Effect):
    name = "amplitude_bias"
    stage = "range"
    nominal = True
    summary = "range bias growing as the amplitude falls: b·((a_ref/a)^γ − 1)"
    Params = AmplitudeBiasParams

    def apply(self, x: np.ndarray, params: AmplitudeBiasParams,
              ctx: RenderContext) -> np.ndarray:
        a = np.maximum(np.nan_to_num(ctx.amplitude), 1e-6)
        ratio = float(params.ref_amplitude) / a
        return x + float(params.bias_mm) * (ratio ** float(params.exponent) - 1.0)
