"""``multipath``: diffuse interreflection of every lit surface, several bounces, with visibility.

See :mod:`..transport` for the equations and :mod:`..world` for the surfaces light travels
through. The world comes from the caller (the simulated cell passes the whole scene) or, when
there is none, from the rendered surface itself (:func:`..reference_world.world_from_surface`:
its pixels plus the support plane extended across the light's cone). ``gain`` scales the
indirect phasor (1 = physical); the other parameters trade accuracy for speed or describe the
light, and are not meant to be fitted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ...surface import SurfaceImage
from ..context import RenderContext
from ..effect import Effect, param
from ..reference_world import world_from_surface
from ..transport import indirect_phasor
from ..world import DEFAULT_BEAM_DEG, DEFAULT_CUTOFF_DEG, DEFAULT_LEAF_MM, WorldModel
from .mixed_pixels import blur_phasor, blur_reach_px


@dataclass(frozen=True)
class MultipathParams:
    """Parameters of :class:`Multipath`."""

    gain: float = param(1.0, 0.0, 5.0, "1", "scale of the indirect phasor (1 = physical)")
    bounces: int = param(3, 1, 4, "1", "diffuse bounces between light and pixel", fit=False)
    leaf_mm: float = param(DEFAULT_LEAF_MM, 1.0, 20.0, "mm", "finest surface patch", fit=False)
    open_ratio: float = param(3.0, 1.5, 20.0, "1",
                              "a patch is gathered whole beyond this many radii", fit=False)
    bounce_patch_mm: float = param(8.0, 2.0, 40.0, "mm",
                                   "patch size at which later bounces are gathered", fit=False)
    cutoff_deg: float = param(DEFAULT_CUTOFF_DEG, 20.0, 90.0, "deg",
                              "half-angle of the light's cone (nothing beyond)", fit=False)
    beam_deg: float = param(DEFAULT_BEAM_DEG, 10.0, 90.0, "deg",
                            "half-angle of full intensity (linear falloff to the cutoff)",
                            fit=False)


class Multipath(Effect):
    name = "multipath"
    stage = "phasor"
    nominal = True
    summary = "diffuse interreflection of every lit surface (three bounces), with visibility"
    Params = MultipathParams
    light_transport = True

    def apply(self, x: np.ndarray, params: MultipathParams,
              ctx: RenderContext) -> np.ndarray:
        world = ctx.world
        if not ctx.surface.valid.any():
            ctx.multipath_phasor = np.zeros(x.shape, np.complex128)
            return x
        if world is None:
            world = self.surface_world(ctx.surface, params)
        if not np.array_equal(ctx.camera_shift, np.eye(4)):
            # the camera (and its pixels) sits where the geometry effects moved it
            world = world.moved_camera(world.camera_to_world @ ctx.camera_shift)
        indirect = self.unit_indirect(ctx.surface, world, params, ctx.mod_freq_hz,
                                      ctx.light_power,
                                      _widened(ctx.receivers, ctx.footprint_sigma_px))
        return self.add_indirect(x, indirect, params, ctx)

    @staticmethod
    def surface_world(surface: SurfaceImage, params: MultipathParams) -> WorldModel:
        """The world light travels through when only ``surface`` is known: its pixels plus the
        support plane extended across the light's cone."""
        return world_from_surface(surface, leaf_mm=float(params.leaf_mm),
                                  cutoff_deg=float(params.cutoff_deg),
                                  beam_deg=float(params.beam_deg))

    @staticmethod
    def unit_indirect(surface: SurfaceImage, world: WorldModel, params: MultipathParams,
                      mod_freq_hz: float, light_power: float,
                      receivers: np.ndarray | None = None) -> np.ndarray:
        """(H, W) complex128 indirect phasor at every pixel centre of ``surface`` at unit gain
        (simulator amplitude units); ``receivers``: (H, W) bool pixels to compute, or None."""
        return indirect_phasor(surface, world, mod_freq_hz=mod_freq_hz, light_power=light_power,
                               bounces=int(params.bounces), open_ratio=float(params.open_ratio),
                               bounce_patch_mm=float(params.bounce_patch_mm),
                               receivers=receivers)

    @staticmethod
    def add_indirect(x: np.ndarray, indirect: np.ndarray, params: MultipathParams,
                     ctx: RenderContext) -> np.ndarray:
        """(H, W) complex128 ``x`` plus ``gain`` × the unit-gain ``indirect`` mixed over each
        pixel's footprint (``ctx.footprint_sigma_px``), kept at ``ctx.receivers``; sets
        ``ctx.multipath_phasor``."""
        # a pixel integrates the indirect light over its footprint as it does the direct: at
        # a crease a pixel partly on a grazing side face gets part of that face's multipath
        indirect = blur_phasor(indirect, ctx.footprint_sigma_px)
        if ctx.receivers is not None:
            indirect = np.where(ctx.receivers, indirect, 0.0)
        ctx.multipath_phasor = float(params.gain) * indirect
        return x + ctx.multipath_phasor


def _widened(receivers: np.ndarray | None, sigma_px: float) -> np.ndarray | None:
    """(H, W) bool receivers grown by the footprint blur's reach, so that the kept pixels'
    footprint mix is exactly what it would be with every pixel a receiver."""
    reach = blur_reach_px(sigma_px)
    if receivers is None or reach == 0:
        return receivers
    # a square: the blur's kernel reaches the diagonal neighbours too
    return ndimage.binary_dilation(receivers, np.ones((2 * reach + 1,) * 2, bool))
