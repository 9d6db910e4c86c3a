"""``lens_scatter``: veiling glare from scattering inside the lens and sensor stack.

A fraction f of every pixel's phasor is spread over the image by a wide Gaussian PSF of σ px:
``Z' = (1 − f) Z + f · G_σ ∗ Z``. Bright near surfaces thus pull the range of dim far pixels
towards their own. Light scattered beyond the image border is lost; light from surfaces outside
the field of view is not modelled.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy import ndimage

from ..context import RenderContext
from ..effect import Effect, ParamSpec


class LensScatter(Effect):
    name = "lens_scatter"
    stage = "phasor"
    summary = "a fraction of each pixel's phasor spread over the image by a wide PSF"
    params = (
        ParamSpec("fraction", 0.02, 0.0, 0.2, "1", "share of each pixel's light scattered"),
        ParamSpec("sigma_px", 25.0, 5.0, 80.0, "px", "width of the scatter PSF"),
    )

    def apply(self, x: np.ndarray, params: Mapping[str, Any],
              ctx: RenderContext) -> np.ndarray:
        frac = float(params["fraction"])
        sigma = float(params["sigma_px"])
        glare = (ndimage.gaussian_filter(x.real, sigma, mode="constant", truncate=3.0)
                 + 1j * ndimage.gaussian_filter(x.imag, sigma, mode="constant", truncate=3.0))
        return (1.0 - frac) * x + frac * glare
