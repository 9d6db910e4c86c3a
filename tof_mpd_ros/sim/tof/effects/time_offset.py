"""``time_offset``: the ToF stamp is offset from the arm pose it is paired with.

A frame stamped t was really exposed at t + Δt, so while the arm moves the camera sees the scene
from the pose it has Δt later: moved by ``v Δt`` and rotated by ``ω Δt`` (constant velocity over
Δt, taken from ``ctx.motion`` in the camera frame). The image shift is proportional to the camera
motion; with the camera at rest (``ctx.motion is None`` or zero) the effect does nothing.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ...surface import SurfaceImage
from ..context import RenderContext
from ..effect import Effect, ParamSpec
from ._geometry import moved_surface


class TimeOffset(Effect):
    name = "time_offset"
    stage = "geometry"
    summary = "ToF stamp vs pose offset: geometry seen from the pose Δt later along the motion"
    params = (
        ParamSpec("offset_ms", 0.0, -100.0, 100.0, "ms",
                  "exposure time minus stamp (positive: the camera is ahead of its pose)"),
    )

    def apply(self, x: SurfaceImage, params: Mapping[str, Any],
              ctx: RenderContext) -> SurfaceImage:
        if ctx.motion is None:
            return x
        dt = 1e-3 * float(params["offset_ms"])
        rot = np.asarray(ctx.motion.angular_rad_s, dtype=np.float64) * dt
        trans = np.asarray(ctx.motion.linear_mm_s, dtype=np.float64) * dt
        return moved_surface(x, rot, trans, ctx)
