"""AMCW phasor arithmetic: range <-> phase, the direct return, and phasor -> (range, amplitude).

Amplitude convention used by the whole simulator: a return's amplitude is π times the radiance the
pixel sees, in units set by ``light_power`` P (amplitude·mm²). The direct return of a Lambertian
patch of albedo ρ at range r lit at incidence cos θ is then ``a = P ρ cos θ / r²`` and every
indirect return computed by :mod:`.transport` uses the same scale, so ratios are physical.
"""

from __future__ import annotations

import math

import numpy as np

# Speed of light in mm/s.
SPEED_OF_LIGHT_MM_S = 299_792_458.0 * 1e3


def ambiguity_range_mm(mod_freq_hz: float) -> float:
    """Unambiguous range c / (2 f) of an AMCW camera, in mm."""
    return SPEED_OF_LIGHT_MM_S / (2.0 * mod_freq_hz)


def phase_per_mm(mod_freq_hz: float) -> float:
    """Phase (rad) accumulated per mm of *radial range* (round trip): 4π f / c."""
    return 4.0 * math.pi * mod_freq_hz / SPEED_OF_LIGHT_MM_S


def direct_phasor(range_mm: np.ndarray, normal: np.ndarray, albedo: np.ndarray,
                  rays: np.ndarray, mod_freq_hz: float, light_power: float) -> np.ndarray:
    """Phasor of the direct return of each sample (co-located point light, Lambertian).

    Args:
        range_mm: (H, W) float64 radial range in mm, NaN = no hit.
        normal: (H, W, 3) float64 unit normals facing the camera.
        albedo: (H, W) float64 diffuse reflectance in [0, 1].
        rays: (H, W, 3) float64 unit ray directions of the samples.
        mod_freq_hz: modulation frequency in Hz.
        light_power: P in amplitude·mm² (amplitude of a ρ = 1 patch at 1 mm, normal incidence).

    Returns:
        (H, W) complex128 phasor ``P ρ cosθ / r² · exp(i 4π f r / c)``; 0 where there is no hit
        or the surface faces away.
    """
    cos_in = np.clip(-np.einsum("hwk,hwk->hw", normal, rays), 0.0, 1.0)
    hit = np.isfinite(range_mm) & np.isfinite(cos_in)
    r = np.where(hit, range_mm, 1.0)
    amp = np.where(hit, light_power * albedo * np.nan_to_num(cos_in) / (r * r), 0.0)
    return amp * np.exp(1j * phase_per_mm(mod_freq_hz) * r)


def phasor_to_range(phasor: np.ndarray, mod_freq_hz: float) -> np.ndarray:
    """Wrapped radial range of each phasor, in [0, c/2f) mm.

    Args:
        phasor: (H, W) complex phasors.

    Returns:
        (H, W) float64 range in mm (angle / (4π f / c), wrapped to one ambiguity interval).
    """
    phase = np.mod(np.angle(phasor), 2.0 * math.pi)
    return phase / phase_per_mm(mod_freq_hz)


def unwrap_to_guide(range_mm: np.ndarray, guide_mm: np.ndarray,
                    mod_freq_hz: float) -> np.ndarray:
    """Add the whole number of ambiguity intervals that brings ``range_mm`` nearest ``guide_mm``.

    This is the ideal unwrapping oracle used when the ``phase_wrapping`` effect is off.

    Args:
        range_mm: (H, W) wrapped range in mm.
        guide_mm: (H, W) true range in mm (NaN where unknown: left wrapped).

    Returns:
        (H, W) float64 unwrapped range in mm.
    """
    amb = ambiguity_range_mm(mod_freq_hz)
    turns = np.round(np.nan_to_num(guide_mm - range_mm) / amb)
    return range_mm + turns * amb
