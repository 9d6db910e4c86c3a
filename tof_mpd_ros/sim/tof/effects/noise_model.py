"""``noise_model``: the camera's noise does not follow the nominal law.

Replaces the ``noise`` stage (the pipeline runs this instead of ``noise`` when enabled) with

    σ² = scale² · (read_std² + shot_gain · (a + ambient)^exponent)

using the ``noise`` effect's read_std, shot_gain and ambient, plus an amplitude-independent phase
jitter of ``jitter_mm`` (range std in mm, e.g. modulation clock jitter).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ..context import RenderContext
from ..effect import Effect, ParamSpec
from ..phasor import phase_per_mm
from .noise import add_noise, phasor_noise_std


class NoiseModel(Effect):
    name = "noise_model"
    stage = "phasor"
    summary = "wrong noise scaling: scaled variance, other amplitude exponent, phase jitter"
    params = (
        ParamSpec("scale", 1.5, 0.1, 4.0, "1", "multiplies the noise std"),
        ParamSpec("exponent", 1.0, 0.5, 2.0, "1", "power of the amplitude in the shot term"),
        ParamSpec("jitter_mm", 0.0, 0.0, 5.0, "mm", "amplitude-independent range noise std"),
    )

    def apply(self, x: np.ndarray, params: Mapping[str, Any],
              ctx: RenderContext) -> np.ndarray:
        nominal = ctx.noise_params
        sigma = phasor_noise_std(np.abs(x), float(nominal["read_std"]),
                                 float(nominal["shot_gain"]), float(nominal["ambient"]),
                                 scale=float(params["scale"]),
                                 exponent=float(params["exponent"]))
        out = add_noise(x, sigma, ctx.rng)
        jitter = float(params["jitter_mm"])
        if jitter > 0:
            phase = ctx.rng.standard_normal(x.shape) * jitter * phase_per_mm(ctx.mod_freq_hz)
            out = out * np.exp(1j * phase)
        return out
