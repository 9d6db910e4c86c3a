"""``multipath``: one-bounce diffuse interreflection added to each pixel's phasor.

See :mod:`..transport` for the equation. ``gain`` scales the indirect phasor (1 = physical); the
other parameters trade accuracy for speed and are not meant to be fitted.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ..context import RenderContext
from ..effect import Effect, ParamSpec
from ..transport import indirect_phasor


class Multipath(Effect):
    name = "multipath"
    stage = "phasor"
    nominal = True
    summary = "diffuse interreflection (camera → y → x → camera) with visibility, one bounce"
    params = (
        ParamSpec("gain", 1.0, 0.0, 3.0, "1",
                  "scale of the indirect phasor (1 = physical; >1 stands in for more bounces)"),
        ParamSpec("block_px", 3, 1, 6, "px", "sender block size", fit=False),
        ParamSpec("step_px", 3.0, 1.0, 8.0, "px", "visibility march spacing", fit=False),
        ParamSpec("max_steps", 8, 0, 32, "1", "most visibility samples per pair", fit=False),
    )

    def apply(self, x: np.ndarray, params: Mapping[str, Any],
              ctx: RenderContext) -> np.ndarray:
        indirect = indirect_phasor(ctx.surface, mod_freq_hz=ctx.mod_freq_hz,
                                   light_power=ctx.light_power, block_px=int(params["block_px"]),
                                   step_px=float(params["step_px"]),
                                   max_steps=int(params["max_steps"]),
                                   receivers=ctx.receivers)
        ctx.multipath_phasor = float(params["gain"]) * indirect
        return x + ctx.multipath_phasor
