"""``lens_scatter``: veiling glare from scattering inside the lens and sensor stack.

A fraction f of every pixel's phasor is spread over the image by a wide Gaussian PSF of σ px:
``Z' = (1 − f) Z + f · G_σ ∗ Z``. Bright near surfaces thus pull the range of dim far pixels
towards their own. Light scattered beyond the image border is lost; light from surfaces outside
the field of view is not modelled.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..context import RenderContext
from ..effect import Effect, param


@dataclass(frozen=True)
class LensScatterParams:
    """Parameters of :class:`LensScatter`."""

    fraction: float = param(0.02, 0.0, 0.2, "1", "share of each pixel's light scattered")
    sigma_px: float = param(25.0, 5.0, 80.0, "px", "width of the scatter PSF")


def gaussian_glare(x: np.ndarray, sigma: float) -> np.ndarray:
    """(H, W) complex128 ``x`` blurred by the scatter PSF of σ px (light beyond the border is
    lost: zero padding, kernel truncated at 3σ)."""
    return (ndimage.gaussian_filter(x.real, sigma, mode="constant", truncate=3.0)
            + 1j * ndimage.gaussian_filter(x.imag, sigma, mode="constant", truncate=3.0))


class LensScatter(Effect):
    name = "lens_scatter"
    stage = "phasor"
    summary = "a fraction of each pixel's phasor spread over the image by a wide PSF"
    Params = LensScatterParams
    mixes_pixels = True

    def apply(self, x: np.ndarray, params: LensScatterParams,
              ctx: RenderContext) -> np.ndarray:
        return self.scatter(x, params, gaussian_glare)

    @staticmethod
    def scatter(x: np.ndarray, params: LensScatterParams,
                glare: Callable[[np.ndarray, float], np.ndarray]) -> np.ndarray:
        """The package's one implementation of the scatter equation ``(1 − f) Z + f · G_σ ∗ Z``
        on (H, W) complex128 phasors, with ``glare(Z, σ)`` computing ``G_σ ∗ Z`` (the mismatch
        predictor passes an FFT version of :func:`gaussian_glare` for wide PSFs)."""
        frac = float(params.fraction)
        return (1.0 - frac) * x + frac * glare(x, float(params.sigma_px))
