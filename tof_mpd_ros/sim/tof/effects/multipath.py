"""``multipath``: diffuse interreflection of every lit surface, several bounces, with visibility.

See :mod:`..transport` for the equations and :mod:`..world` for the surfaces light travels
through. The world comes from the caller (the simulated cell passes the whole scene) or, when
there is none, from the rendered surface itself (:func:`..reference_world.world_from_surface`:
its pixels plus the support plane extended across the light's cone). ``gain`` scales the
indirect phasor (1 = physical); the other parameters trade accuracy for speed or describe the
light, and are not meant to be fitted.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy import ndimage

from ..context import RenderContext
from ..effect import Effect, ParamSpec
from ..reference_world import world_from_surface
from ..transport import indirect_phasor
from ..world import DEFAULT_BEAM_DEG, DEFAULT_CUTOFF_DEG, DEFAULT_LEAF_MM
from .mixed_pixels import blur_phasor, blur_reach_px


class Multipath(Effect):
    name = "multipath"
    stage = "phasor"
    nominal = True
    summary = "diffuse interreflection of every lit surface (three bounces), with visibility"
    params = (
        ParamSpec("gain", 1.0, 0.0, 5.0, "1", "scale of the indirect phasor (1 = physical)"),
        ParamSpec("bounces", 3, 1, 4, "1", "diffuse bounces between light and pixel", fit=False),
        ParamSpec("leaf_mm", DEFAULT_LEAF_MM, 1.0, 20.0, "mm", "finest surface patch",
                  fit=False),
        ParamSpec("open_ratio", 3.0, 1.5, 20.0, "1",
                  "a patch is gathered whole beyond this many radii", fit=False),
        ParamSpec("bounce_patch_mm", 8.0, 2.0, 40.0, "mm",
                  "patch size at which later bounces are gathered", fit=False),
        ParamSpec("cutoff_deg", DEFAULT_CUTOFF_DEG, 20.0, 90.0, "deg",
                  "half-angle of the light's cone (nothing beyond)", fit=False),
        ParamSpec("beam_deg", DEFAULT_BEAM_DEG, 10.0, 90.0, "deg",
                  "half-angle of full intensity (linear falloff to the cutoff)", fit=False),
    )

    def apply(self, x: np.ndarray, params: Mapping[str, Any],
              ctx: RenderContext) -> np.ndarray:
        world = ctx.world
        if not ctx.surface.valid.any():
            ctx.multipath_phasor = np.zeros(x.shape, np.complex128)
            return x
        if world is None:
            world = world_from_surface(ctx.surface, leaf_mm=float(params["leaf_mm"]),
                                       cutoff_deg=float(params["cutoff_deg"]),
                                       beam_deg=float(params["beam_deg"]))
        if not np.array_equal(ctx.camera_shift, np.eye(4)):
            # the camera (and its pixels) sits where the geometry effects moved it
            world = world.moved_camera(world.camera_to_world @ ctx.camera_shift)
        indirect = indirect_phasor(ctx.surface, world, mod_freq_hz=ctx.mod_freq_hz,
                                   light_power=ctx.light_power, bounces=int(params["bounces"]),
                                   open_ratio=float(params["open_ratio"]),
                                   bounce_patch_mm=float(params["bounce_patch_mm"]),
                                   receivers=_widened(ctx.receivers, ctx.footprint_sigma_px))
        # a pixel integrates the indirect light over its footprint as it does the direct: at
        # a crease a pixel partly on a grazing side face gets part of that face's multipath
        indirect = blur_phasor(indirect, ctx.footprint_sigma_px)
        if ctx.receivers is not None:
            indirect = np.where(ctx.receivers, indirect, 0.0)
        ctx.multipath_phasor = float(params["gain"]) * indirect
        return x + ctx.multipath_phasor


def _widened(receivers: np.ndarray | None, sigma_px: float) -> np.ndarray | None:
    """(H, W) bool receivers grown by the footprint blur's reach, so that the kept pixels'
    footprint mix is exactly what it would be with every pixel a receiver."""
    reach = blur_reach_px(sigma_px)
    if receivers is None or reach == 0:
        return receivers
    # a square: the blur's kernel reaches the diagonal neighbours too
    return ndimage.binary_dilation(receivers, np.ones((2 * reach + 1,) * 2, bool))
