"""``subsurface``: light that enters a material and re-emerges later and a little further on.

For pixels of material m a fraction f_m of the phasor is delayed by an extra path of δ_m mm
(range grows by δ_m, phase by 4π f δ_m / c) and spread by a Gaussian of σ_m px within the
material's own pixels (normalised there, so no light crosses onto other materials):

    Z' = (1 − f_m) Z + f_m · e^{i 4π f δ_m / c} · blur_m(Z)

Per-material parameters are tuples indexed by ``material_id``; materials beyond the tuple use
its last entry. A reference image carries material 0 everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..context import RenderContext
from ..effect import Effect, param
from ..phasor import phase_per_mm
from .mixed_pixels import blur_phasor


def per_material(values: Any, material: int) -> float:
    """Entry ``material`` of a per-material tuple (scalars apply to every material)."""
    seq = np.atleast_1d(np.asarray(values, dtype=np.float64))
    return float(seq[min(max(material, 0), seq.size - 1)])


@dataclass(frozen=True)
class SubsurfaceParams:
    """Parameters of :class:`Subsurface`: one entry per material (the last one for the rest)."""

    delay_mm: tuple[float, ...] = param((3.0,), 0.0, 30.0, "mm",
                                        "extra range of the subsurface part")
    sigma_px: tuple[float, ...] = param((1.0,), 0.0, 6.0, "px",
                                        "spatial spread of the subsurface part")
    fraction: tuple[float, ...] = param((0.3,), 0.0, 1.0, "1",
                                        "share of the light scattered below")


class Subsurface(Effect):
    name = "subsurface"
    stage = "phasor"
    summary = "per-material extra delay and small spatial blur of the phasor"
    Params = SubsurfaceParams
    mixes_pixels = True

    def apply(self, x: np.ndarray, params: SubsurfaceParams,
              ctx: RenderContext) -> np.ndarray:
        out = x.copy()
        material = ctx.surface.material_id
        for m in np.unique(material[material >= 0]):
            mask = material == m
            frac = per_material(params.fraction, int(m))
            delay = per_material(params.delay_mm, int(m))
            sigma = per_material(params.sigma_px, int(m))
            spread = blur_phasor(np.where(mask, x, 0.0), sigma)
            weight = blur_phasor(mask.astype(np.complex128), sigma).real
            with np.errstate(invalid="ignore", divide="ignore"):
                spread = np.where(weight > 1e-6, spread / weight, 0.0)
            delayed = spread * np.exp(1j * phase_per_mm(ctx.mod_freq_hz) * delay)
            out[mask] = (1.0 - frac) * x[mask] + frac * delayed[mask]
        return out
