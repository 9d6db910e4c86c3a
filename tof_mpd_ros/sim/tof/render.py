"""Render a ToF measurement: from a (supersampled) surface image, or from a reference range image.

Pipeline (:mod:`.pipeline`, the order the mismatch predictor walks too; each named effect can be
switched off in :class:`.config.ToFConfig`):

1. geometry: ``hand_eye``, ``time_offset`` re-render the surface from the true camera pose;
2. direct return of every sample, ``P ρ cosθ / r² · e^{i 4π f r / c}``;
3. footprint: ``mixed_pixels`` integrates the samples over each pixel (off: centre ray only);
4. phasor: ``multipath`` (over a :class:`.world.WorldModel`), ``subsurface``, ``lens_scatter``,
   then ``noise`` (or ``noise_model``);
5. readout: range from the phasor's angle, wrapping at c/2f (``phase_wrapping``), amplitude from
   its magnitude;
6. range: ``wiggling``, ``amplitude_bias``, ``pixel_offset``, ``temperature_drift``;
7. pixels with no hit or an amplitude below ``min_amplitude`` become NaN.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...camera import Intrinsics
from ...errors import InputError
from ...frame import ToFFrame
from ..surface import SurfaceImage
from .config import ToFConfig
from .context import CameraMotion, RenderContext
from .phasor import direct_phasor, phasor_to_range, unwrap_to_guide
from .pipeline import Action, Step, frame_context, pipeline_steps, run_step
from .rays import ray_directions
from .reference import surface_from_reference
from .reference_world import ReferenceView, world_from_surface
from .registry import EFFECTS
from .world import WorldModel


@dataclass
class ToFMeasurement:
    """A simulated ToF frame and the components it was made of.

    Attributes:
        range_mm: (H, W) float32 measured radial range in mm; NaN = invalid (no hit or amplitude
            below the floor).
        amplitude: (H, W) float32 measured amplitude (simulator units, see :mod:`.phasor`),
            NaN where the range is invalid.
        intrinsics: intrinsics of the H x W pixel grid.
        mod_freq_hz: modulation frequency in Hz.
        true_range_mm: (H, W) float32 range of the surface on each pixel's centre ray, mm
            (after geometry effects), NaN = no hit.
        direct_range_mm: (H, W) float32 range of the direct-only phasor after the footprint
            (mixed pixels, no multipath, noise or systematic errors), mm.
        direct_phasor: (H, W) complex64 direct phasor after the footprint.
        multipath_phasor: (H, W) complex64 indirect phasor, or None when multipath is off.
    """

    range_mm: np.ndarray
    amplitude: np.ndarray
    intrinsics: Intrinsics
    mod_freq_hz: float
    true_range_mm: np.ndarray
    direct_range_mm: np.ndarray
    direct_phasor: np.ndarray
    multipath_phasor: np.ndarray | None = None

    @property
    def valid(self) -> np.ndarray:
        """(H, W) bool: pixels with a measured range."""
        return np.isfinite(self.range_mm)

    def to_frame(self, *, stamp_ns: int = 0, pose: np.ndarray | None = None,
                 reference_mm: np.ndarray | None = None) -> ToFFrame:
        """The measurement as a :class:`ToFFrame` (range and amplitude, optional reference)."""
        return ToFFrame(range_mm=self.range_mm, amplitude=self.amplitude,
                        intrinsics=self.intrinsics, mod_freq_hz=self.mod_freq_hz,
                        reference_mm=reference_mm, stamp_ns=stamp_ns, pose=pose)


def pixel_intrinsics(sample_intrinsics: Intrinsics, supersample: int) -> Intrinsics:
    """Inverse of :meth:`Intrinsics.scaled`: the pixel grid of a supersampled grid."""
    s = float(supersample)
    k = sample_intrinsics
    return Intrinsics(k.fx / s, k.fy / s, (k.cx + 0.5) / s - 0.5, (k.cy + 0.5) / s - 0.5,
                      k.width // supersample, k.height // supersample)


def centre_samples(samples: SurfaceImage, supersample: int) -> SurfaceImage:
    """One sample per pixel: the one nearest the pixel centre (exactly on it for odd s)."""
    s = supersample
    if s == 1:
        return samples
    c = s // 2
    pick = (slice(c, None, s), slice(c, None, s))
    return SurfaceImage(range_mm=samples.range_mm[pick], normal=samples.normal[pick],
                        albedo=samples.albedo[pick], object_id=samples.object_id[pick],
                        material_id=samples.material_id[pick],
                        intrinsics=pixel_intrinsics(samples.intrinsics, s))


def _check_inputs(surface: SurfaceImage, config: ToFConfig, rng: np.random.Generator,
                  supersample: int) -> None:
    if not isinstance(surface, SurfaceImage):
        raise InputError(f"surface: expected a SurfaceImage, got {type(surface).__name__}")
    if not isinstance(config, ToFConfig):
        raise InputError(f"config: expected a ToFConfig, got {type(config).__name__}")
    if not isinstance(rng, np.random.Generator):
        raise InputError(f"rng: expected a numpy Generator, got {type(rng).__name__}")
    if not (isinstance(supersample, (int, np.integer)) and supersample >= 1):
        raise InputError(f"supersample: expected an integer >= 1, got {supersample!r}")
    h, w = surface.intrinsics.shape
    if h % supersample or w % supersample:
        raise InputError(f"surface grid {w}x{h} is not a multiple of supersample={supersample}")


def _footprint_hit(samples: SurfaceImage, s: int, mixing: bool) -> np.ndarray:
    """(H, W) bool: the pixel's footprint holds a surface (any sample, or the centre one)."""
    hit = samples.valid
    if s == 1:
        return hit
    if not mixing:
        return hit[s // 2::s, s // 2::s]
    h, w = hit.shape[0] // s, hit.shape[1] // s
    return hit.reshape(h, s, w, s).any(axis=(1, 3))


def _run_stage(stage: str, x: Any, steps: tuple[Step, ...], config: ToFConfig,
               ctx: RenderContext, transport: bool = False) -> Any:
    """``x`` through the steps of ``stage`` in pipeline order; with ``transport`` (an external
    renderer's phasor) the light-transport effects are left out: that phasor holds them."""
    for step in steps:
        if step.stage == stage and not (transport and step.effect.light_transport):
            x = run_step(step, x, config, ctx)
    return x


def _receivers(receivers: np.ndarray | None, config: ToFConfig,
               ctx: RenderContext) -> np.ndarray | None:
    """The caller's receivers, or None when an effect that is on mixes every pixel's indirect
    light into its neighbours (then all are needed)."""
    if receivers is None or any(config.effects[name].enabled
                                for name, e in EFFECTS.items() if e.mixes_pixels):
        return None
    receivers = np.asarray(receivers, dtype=bool)
    if receivers.shape != ctx.intrinsics.shape:
        raise InputError(f"receivers: expected shape {ctx.intrinsics.shape}, "
                         f"got {receivers.shape}")
    return receivers


def _render(samples: SurfaceImage, config: ToFConfig, rng: np.random.Generator,
            supersample: int, frame_index: int, motion: CameraMotion | None,
            receivers: np.ndarray | None = None,
            world: WorldModel | None = None,
            transport: np.ndarray | None = None) -> ToFMeasurement:
    """The stages of :data:`.pipeline.STAGE_ORDER` in turn (see :func:`render_tof`)."""
    s = supersample
    steps = pipeline_steps()
    ctx = frame_context(config, pixel_intrinsics(samples.intrinsics, s), samples, rng=rng,
                        supersample=s, frame_index=frame_index, motion=motion, world=world)
    ctx.receivers = _receivers(receivers, config, ctx)
    samples = _run_stage("geometry", samples, steps, config, ctx)
    ctx.samples = samples
    ctx.surface = centre_samples(samples, s)
    ctx.true_range_mm = ctx.surface.range_mm

    if transport is None:  # DIRECT, then the footprint
        z_samples = direct_phasor(samples.range_mm, samples.normal, samples.albedo,
                                  ray_directions(samples.intrinsics), config.mod_freq_hz,
                                  config.light_power)
        direct = _run_stage("footprint", z_samples, steps, config, ctx)
    else:
        # an external renderer did the light transport (footprint and multipath included)
        direct = np.asarray(transport, dtype=np.complex128)
        if direct.shape != ctx.intrinsics.shape:
            raise InputError(f"transport: expected shape {ctx.intrinsics.shape}, "
                             f"got {direct.shape}")
    z = _run_stage("phasor", direct, steps, config, ctx, transport=transport is not None)
    ctx.amplitude = amplitude = np.abs(z)
    range_mm = _run_stage("range", _run_stage("readout", z, steps, config, ctx), steps, config,
                          ctx)

    mixing = any(step.action(config) is Action.APPLY for step in steps
                 if step.stage == "footprint")
    valid = _footprint_hit(samples, s, mixing) & (amplitude >= config.min_amplitude)
    direct_range = unwrap_to_guide(phasor_to_range(direct, config.mod_freq_hz),
                                   ctx.true_range_mm, config.mod_freq_hz)
    mp = ctx.multipath_phasor
    return ToFMeasurement(
        range_mm=np.where(valid, range_mm, np.nan).astype(np.float32),
        amplitude=np.where(valid, amplitude, np.nan).astype(np.float32),
        intrinsics=ctx.intrinsics, mod_freq_hz=config.mod_freq_hz,
        true_range_mm=ctx.true_range_mm.astype(np.float32),
        direct_range_mm=np.where(np.abs(direct) > 0, direct_range, np.nan).astype(np.float32),
        direct_phasor=direct.astype(np.complex64),
        multipath_phasor=None if mp is None else mp.astype(np.complex64))


def render_tof(surface: SurfaceImage, config: ToFConfig, rng: np.random.Generator, *,
               supersample: int, frame_index: int = 0,
               motion: CameraMotion | None = None,
               receivers: np.ndarray | None = None,
               world: WorldModel | None = None,
               transport: np.ndarray | None = None) -> ToFMeasurement:
    """Simulate the ToF measurement of a ray-cast scene.

    Args:
        surface: supersampled surface image (``supersample`` × ``supersample`` samples per
            pixel; intrinsics = ``pixel_intrinsics.scaled(supersample)``).
        config: camera and effect configuration.
        rng: random generator (noise); the result is a deterministic function of its state.
        supersample: samples per pixel and axis (odd values put a sample on the pixel centre).
        frame_index: index of the frame in its sequence (temperature drift).
        motion: camera velocity during the frame (time offset), None = at rest.
        receivers: (H, W) bool, the pixels the caller keeps (None = all). ``multipath``, the
            costly step, then computes the indirect light only for them (every pixel still
            sends light), so a caller that crops a margin away pays nothing for the margin.
            The kept pixels come out exactly as without it; the others lack the indirect
            light. Ignored when ``subsurface`` or ``lens_scatter`` (which mix neighbouring
            pixels after multipath) is on.
        world: every surface light travels through, with the camera's pose in it
            (:func:`.world.world_from_scene` for a simulated scene); None = infer it from
            ``surface`` (:func:`.reference_world.world_from_surface`).
        transport: (H, W) complex128 per-pixel phasor of the whole light transport (direct and
            indirect, integrated over each pixel's footprint) from another renderer, e.g. the
            path tracer (:mod:`tof_mpd_ros.sim.pathtrace`), in the simulator's amplitude units;
            the footprint and ``multipath`` stages are then skipped and the camera's own
            modules (scatter, noise, readout, systematic errors) act on it. ``direct_phasor``
            of the result then holds it whole.

    Returns:
        ToFMeasurement on the H x W = surface grid / supersample pixel grid.

    Raises:
        InputError: wrong argument types or a grid not divisible by ``supersample``.
        SimulationError: an effect could not be applied.
    """
    _check_inputs(surface, config, rng, supersample)
    return _render(surface, config, rng, int(supersample), frame_index, motion, receivers,
                   world, transport)


def render_from_reference(reference_range: np.ndarray, intrinsics: Intrinsics,
                          albedo: np.ndarray | float | None = None,
                          config: ToFConfig | None = None,
                          rng: np.random.Generator | None = None, *, frame_index: int = 0,
                          motion: CameraMotion | None = None,
                          material_id: np.ndarray | None = None,
                          camera_to_world_mm: np.ndarray | None = None,
                          other_views: Sequence[ReferenceView] = ()) -> ToFMeasurement:
    """Predict the ToF measurement of a scene given as a reference range image.

    The reference is the geometry: normals come from its gradient, missing pixels stay missing,
    and mixed pixels are modelled by mixing each pixel's phasor with its neighbours. Light
    transport runs over the world inferred from it (:func:`.reference_world.world_from_surface`:
    the support plane extended across the light's cone) and, given poses, over the surfaces
    that only ``other_views`` of the same scene saw.

    Args:
        reference_range: (H, W) float radial range in mm, NaN = missing.
        intrinsics: intrinsics of the H x W image.
        albedo: (H, W) albedo in [0, 1], a scalar, or None (0.5).
        config: camera and effect configuration (None = nominal).
        rng: random generator for noise (None = ``np.random.default_rng(0)``).
        frame_index: index of the frame in its sequence (temperature drift).
        motion: camera velocity during the frame (time offset), None = at rest.
        material_id: (H, W) int material index (subsurface), None = material 0.
        camera_to_world_mm: (4, 4) pose of this view in the robot's base frame (mm, +z up),
            needed with ``other_views``; with it the support plane must be about horizontal.
        other_views: other references of the same scene with their poses (same intrinsics).

    Returns:
        ToFMeasurement on the reference's pixel grid.

    Raises:
        InputError: bad reference, intrinsics, albedo or views.
    """
    config = ToFConfig.nominal() if config is None else config
    rng = np.random.default_rng(0) if rng is None else rng
    surface = surface_from_reference(reference_range, intrinsics, albedo, material_id)
    _check_inputs(surface, config, rng, 1)
    world = None
    if other_views and camera_to_world_mm is None:
        raise InputError("other_views need this view's camera_to_world_mm")
    if camera_to_world_mm is not None and config.effects["multipath"].enabled and \
            surface.valid.any():
        p = config.params("multipath")
        others = tuple((surface_from_reference(v.reference_mm, intrinsics, v.albedo),
                        np.asarray(v.camera_to_world_mm, np.float64)) for v in other_views)
        # the world is the robot's base frame: +z is up
        world = world_from_surface(surface, leaf_mm=float(p["leaf_mm"]),
                                   cutoff_deg=float(p["cutoff_deg"]),
                                   beam_deg=float(p["beam_deg"]), others=others,
                                   camera_to_world=camera_to_world_mm,
                                   world_up=np.array([0.0, 0.0, 1.0]))
    return _render(surface, config, rng, 1, frame_index, motion, world=world)


__all__ = ["CameraMotion", "ToFMeasurement", "centre_samples",
           "pixel_intrinsics", "render_from_reference", "render_tof"]
