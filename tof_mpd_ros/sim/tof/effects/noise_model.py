"""``noise_model``: the camera's noise does not follow the nominal law.

Replaces the ``noise`` stage (the pipeline runs this instead of ``noise`` when enabled) with

    σ² = scale² · (read_std² + shot_gain · (a + ambient)^exponent)

using the ``noise`` effect's read_std, shot_gain and ambient, plus an amplitude-independent phase
jitter of ``jitter_mm`` (range std in mm, e.g. modulation clock jitter).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..context import RenderContext
from ..effect import Effect, param
from ..phasor import phase_per_mm
from .noise import Noise, NoiseParams, add_noise, phasor_noise_std


@dataclass(frozen=True)
class NoiseModelParams:
    """Parameters of :class:`NoiseModel`."""

    scale: float = param(1.5, 0.1, 4.0, "1", "multiplies the noise std")
    exponent: float = param(1.0, 0.5, 2.0, "1", "power of the amplitude in the shot term")
    jitter_mm: float = param(0.0, 0.0, 5.0, "mm", "amplitude-independent range noise std")


class NoiseModel(Effect):
    name = "noise_model"
    stage = "phasor"
    summary = "wrong noise scaling: scaled variance, other amplitude exponent, phase jitter"
    Params = NoiseModelParams
    stochastic = True
    replaces = (Noise.name,)

    def apply(self, x: np.ndarray, params: NoiseModelParams,
              ctx: RenderContext) -> np.ndarray:
        nominal = NoiseParams() if ctx.noise_params is None else ctx.noise_params
        sigma = phasor_noise_std(np.abs(x), float(nominal.read_std),
                                 float(nominal.shot_gain), float(nominal.ambient),
                                 scale=float(params.scale),
                                 exponent=float(params.exponent))
        out = add_noise(x, sigma, ctx.rng)
        jitter = float(params.jitter_mm)
        if jitter > 0:
            phase = ctx.rng.standard_normal(x.shape) * jitter * phase_per_mm(ctx.mod_freq_hz)
            out = out * np.exp(1j * phase)
        return out
