"""Shared helper of the pose-error effects (``hand_eye``, ``time_offset``)."""

from __future__ import annotations

import numpy as np

from ...surface import SurfaceImage
from ..warp import move_camera


def moved_surface(surface: SurfaceImage, rotvec: np.ndarray,
                  translation_mm: np.ndarray) -> SurfaceImage:
    """``surface`` from a camera moved by (rotvec rad, translation mm); unchanged when zero."""
    if not (np.any(rotvec) or np.any(translation_mm)):
        return surface
    return move_camera(surface, rotvec, translation_mm)
