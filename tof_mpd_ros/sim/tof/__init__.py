"""AMCW Time-of-Flight measurement physics (docs/physics.md).

Each physical effect is a separate, named, parameterised module (``EFFECTS``) switched on or off
in a :class:`ToFConfig`. Entry points:

* :func:`render_tof` — a ray-cast, supersampled :class:`~tof_mpd_ros.sim.surface.SurfaceImage`
  to a :class:`ToFMeasurement`;
* :func:`render_from_reference` — predict the measurement from a reference range image;
* :func:`surface_from_reference` — the surface image a reference range image describes;
* :func:`pipeline_steps`, :func:`run_step`, :func:`frame_context` — the measurement's steps, for
  a caller that walks them itself (the mismatch tool's predictor);
* :func:`register_effect` — add an effect to the registry, the renderer and the predictor.
"""

from __future__ import annotations

from .config import DEFAULT_LIGHT_POWER, EffectConfig, ToFConfig
from .context import CameraMotion, RenderContext
from .effect import CameraMoveEffect, Effect, NoParams, ParamSpec, param
from .effects.noise import phasor_noise_std
from .effects.wiggling import wiggle_mm
from .phasor import SPEED_OF_LIGHT_MM_S, ambiguity_range_mm, direct_phasor, phase_per_mm
from .pipeline import DIRECT, STAGE_ORDER, Action, Step, frame_context, pipeline_steps, run_step
from .reference import normals_from_range, surface_from_reference
from .registry import (
    EFFECTS,
    NOMINAL_EFFECTS,
    effect_names,
    nominal_effects,
    register_effect,
    unregister_effect,
)
from .render import (
    ToFMeasurement,
    centre_samples,
    pixel_intrinsics,
    render_from_reference,
    render_tof,
)

__all__ = [
    "DEFAULT_LIGHT_POWER", "DIRECT", "EFFECTS", "NOMINAL_EFFECTS", "SPEED_OF_LIGHT_MM_S",
    "STAGE_ORDER", "Action", "CameraMotion", "CameraMoveEffect", "Effect", "EffectConfig",
    "NoParams", "ParamSpec", "RenderContext", "Step", "ToFConfig", "ToFMeasurement",
    "ambiguity_range_mm", "centre_samples", "direct_phasor", "effect_names", "frame_context",
    "nominal_effects",
    "normals_from_range", "param", "phase_per_mm", "phasor_noise_std", "pipeline_steps",
    "pixel_intrinsics", "register_effect", "render_from_reference", "render_tof", "run_step",
    "surface_from_reference", "unregister_effect", "wiggle_mm",
]
