"""``noise``: shot and read noise on the phasor components.

Each of the real and imaginary parts gets independent Gaussian noise of variance

    σ² = read_std² + shot_gain · (a + ambient)

(a = the pixel's noise-free amplitude; shot noise grows with the collected light, ambient light
adds shot noise without signal). For a ≫ σ the range noise is therefore
σ_range = σ / (a · 4π f / c) mm: about 1/a at low amplitude, 1/sqrt(a) at high amplitude.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..context import RenderContext
from ..effect import Effect, param
from ..phasor import phase_per_mm


def phasor_noise_std(amplitude: np.ndarray, read_std: float, shot_gain: float, ambient: float,
                     scale: float = 1.0, exponent: float = 1.0) -> np.ndarray:
    """Per-component noise std (amplitude units) for noise-free amplitude ``amplitude``.

    Args:
        amplitude: (H, W) float64 amplitude >= 0.
        scale, exponent: the ``noise_model`` deviations (1, 1 = nominal).

    Returns:
        (H, W) float64 std of each phasor component.
    """
    var = read_std ** 2 + shot_gain * (amplitude + ambient) ** exponent
    return scale * np.sqrt(var)


def range_noise_std_mm(amplitude: np.ndarray, mod_freq_hz: float, read_std: float,
                       shot_gain: float, ambient: float = 0.0) -> np.ndarray:
    """Predicted range noise std in mm at amplitude ``amplitude`` (valid for a ≫ σ)."""
    sigma = phasor_noise_std(np.asarray(amplitude, dtype=np.float64), read_std, shot_gain,
                             ambient)
    return sigma / (np.asarray(amplitude) * phase_per_mm(mod_freq_hz))


def add_noise(phasor: np.ndarray, sigma: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``phasor`` plus independent N(0, σ²) on its real and imaginary parts."""
    draws = rng.standard_normal((2, *phasor.shape))
    return phasor + sigma * (draws[0] + 1j * draws[1])


@dataclass(frozen=True)
class NoiseParams:
    """Parameters of :class:`Noise` (also read by ``noise_model``)."""

    read_std: float = param(0.5, 0.05, 5.0, "amplitude", "read noise std per component")
    shot_gain: float = param(0.004, 0.0, 0.05, "amplitude",
                             "shot-noise variance per unit of amplitude")
    ambient: float = param(0.0, 0.0, 500.0, "amplitude",
                           "ambient light: adds shot noise, no signal")


class Noise(Effect):
    name = "noise"
    stage = "phasor"
    nominal = True
    summary = "shot + read noise on the phasor components (variance grows with amplitude)"
    Params = NoiseParams
    stochastic = True

    def apply(self, x: np.ndarray, params: NoiseParams,
              ctx: RenderContext) -> np.ndarray:
        sigma = phasor_noise_std(np.abs(x), float(params.read_std),
                                 float(params.shot_gain), float(params.ambient))
        return add_noise(x, sigma, ctx.rng)
