"""``mixed_pixels``: a pixel integrates the phasors over its finite footprint.

The footprint is the pixel's box convolved with a Gaussian optical blur of ``psf_sigma_px``. With
a supersampled surface (s × s samples per pixel) the per-sample phasors are blurred by the
Gaussian (σ·s samples) and box-summed over each pixel, so a pixel on a depth edge reads a range
between foreground and background. From a reference image (one sample per pixel) the pixel's
phasor is mixed with its neighbours by a Gaussian with the same second moment as the footprint,
σ_eff = sqrt(σ² + 1/12) px (:func:`footprint_sigma_px`). ``multipath`` mixes the indirect light,
which it computes at the pixel centres, the same way. Disabled, each pixel sees only the ray
through its centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

from ..context import RenderContext
from ..effect import Effect, param

if TYPE_CHECKING:
    from ..config import ToFConfig


def blur_phasor(phasor: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur of a complex image (σ in samples; edges replicate)."""
    if sigma <= 0:
        return phasor
    re = ndimage.gaussian_filter(phasor.real, sigma, mode="nearest", truncate=3.0)
    im = ndimage.gaussian_filter(phasor.imag, sigma, mode="nearest", truncate=3.0)
    return re + 1j * im


def footprint_sigma_px(psf_sigma_px: float) -> float:
    """σ in pixels of the Gaussian with the second moment of a pixel's footprint (its unit box
    convolved with the optical blur): how far a pixel-centre quantity is mixed."""
    return math.sqrt(psf_sigma_px * psf_sigma_px + 1.0 / 12.0)


def light_footprint_sigma_px(config: ToFConfig) -> float:
    """σ in pixels by which ``config``'s camera mixes light computed at the pixel centres (the
    indirect light) over each pixel's footprint: 0 with ``mixed_pixels`` off."""
    effect = config.effects[MixedPixels.name]
    return footprint_sigma_px(float(effect.params["psf_sigma_px"])) if effect.enabled else 0.0


def blur_reach_px(sigma: float) -> int:
    """Pixels :func:`blur_phasor` reaches on each side (scipy's kernel radius at truncate 3)."""
    return int(3.0 * sigma + 0.5) if sigma > 0 else 0


def box_sum(samples: np.ndarray, s: int) -> np.ndarray:
    """Mean of each s × s block: (s·H, s·W) -> (H, W)."""
    h, w = samples.shape[0] // s, samples.shape[1] // s
    return samples.reshape(h, s, w, s).mean(axis=(1, 3))


@dataclass(frozen=True)
class MixedPixelsParams:
    """Parameters of :class:`MixedPixels`."""

    psf_sigma_px: float = param(0.3, 0.0, 3.0, "px",
                                "Gaussian optical blur on top of the pixel's box footprint")


class MixedPixels(Effect):
    name = "mixed_pixels"
    stage = "footprint"
    nominal = True
    summary = "phasor sum over the pixel footprint: ranges between fore- and background at edges"
    Params = MixedPixelsParams
    light_transport = True

    def apply(self, x: np.ndarray, params: MixedPixelsParams,
              ctx: RenderContext) -> np.ndarray:
        """(s·H, s·W) complex128 sample phasors -> (H, W) complex128 pixel phasors."""
        s = ctx.supersample
        sigma = float(params.psf_sigma_px)
        if s > 1:
            return box_sum(blur_phasor(x, sigma * s), s)
        return blur_phasor(x, footprint_sigma_px(sigma))

    def bypass(self, x: np.ndarray, ctx: RenderContext) -> np.ndarray:
        """Off: each pixel sees only the ray through its centre, (s·H, s·W) -> (H, W)."""
        s = ctx.supersample
        return x[s // 2::s, s // 2::s] if s > 1 else x
