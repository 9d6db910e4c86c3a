"""Shared helper of the pose-error effects (``hand_eye``, ``time_offset``)."""

from __future__ import annotations

import numpy as np

from ....pose import rotvec_to_matrix
from ...surface import SurfaceImage
from ..context import RenderContext
from ..warp import move_camera


def moved_surface(surface: SurfaceImage, rotvec: np.ndarray, translation_mm: np.ndarray,
                  ctx: RenderContext) -> SurfaceImage:
    """``surface`` from a camera moved by (rotvec rad, translation mm); unchanged when zero.

    The move is also composed into ``ctx.camera_shift``, so light transport places the moved
    camera (and its pixels) where it really is in the world.
    """
    if not (np.any(rotvec) or np.any(translation_mm)):
        return surface
    shift = np.eye(4)
    shift[:3, :3] = rotvec_to_matrix(rotvec)
    shift[:3, 3] = translation_mm
    ctx.camera_shift = ctx.camera_shift @ shift
    return move_camera(surface, rotvec, translation_mm)
