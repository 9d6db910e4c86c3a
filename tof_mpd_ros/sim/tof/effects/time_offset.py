"""``time_offset``: the ToF stamp is offset from the arm pose it is paired with.

A frame stamped t was really exposed at t + Δt, so while the arm moves the camera sees the scene
from the pose it has Δt later: moved by ``v Δt`` and rotated by ``ω Δt`` (constant velocity over
Δt, taken from ``ctx.motion`` in the camera frame). The image shift is proportional to the camera
motion; with the camera at rest (``ctx.motion is None`` or zero) the effect does nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..context import RenderContext
from ..effect import CameraMoveEffect, param


@dataclass(frozen=True)
class TimeOffsetParams:
    """Parameters of :class:`TimeOffset`."""

    offset_ms: float = param(0.0, -100.0, 100.0, "ms", "exposure time minus stamp (positive: "
                             "the camera is ahead of its pose)")


class TimeOffset(CameraMoveEffect):
    name = "time_offset"
    summary = "ToF stamp vs pose offset: geometry seen from the pose Δt later along the motion"
    Params = TimeOffsetParams

    def camera_move(self, params: TimeOffsetParams, ctx: RenderContext
                    ) -> tuple[np.ndarray, np.ndarray] | None:
        """``(ω Δt, v Δt)`` of the camera's motion, None when it is at rest (no motion given)."""
        if ctx.motion is None:
            return None
        dt = 1e-3 * float(params.offset_ms)
        rot = np.asarray(ctx.motion.angular_rad_s, dtype=np.float64) * dt
        trans = np.asarray(ctx.motion.linear_mm_s, dtype=np.float64) * dt
        return rot, trans
