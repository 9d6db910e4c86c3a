"""AMCW Time-of-Flight measurement physics (docs/physics.md).

Each physical effect is a separate, named, parameterised module (``EFFECTS``) switched on or off
in a :class:`ToFConfig`. Entry points:

* :func:`render_tof` — a ray-cast, supersampled :class:`~tof_mpd_ros.sim.surface.SurfaceImage`
  to a :class:`ToFMeasurement`;
* :func:`render_from_reference` — predict the measurement from a reference range image;
* :func:`surface_from_reference` — the surface image a reference range image describes.
"""

from __future__ import annotations

from .config import EffectConfig, ToFConfig
from .context import CameraMotion
from .effect import Effect, ParamSpec
from .phasor import SPEED_OF_LIGHT_MM_S, ambiguity_range_mm, phase_per_mm
from .reference import surface_from_reference
from .registry import EFFECTS, NOMINAL_EFFECTS, effect_names
from .render import ToFMeasurement, pixel_intrinsics, render_from_reference, render_tof

__all__ = [
    "EFFECTS", "NOMINAL_EFFECTS", "SPEED_OF_LIGHT_MM_S", "CameraMotion", "Effect",
    "EffectConfig", "ParamSpec", "ToFConfig", "ToFMeasurement", "ambiguity_range_mm",
    "effect_names", "phase_per_mm", "pixel_intrinsics", "render_from_reference", "render_tof",
    "surface_from_reference",
]
