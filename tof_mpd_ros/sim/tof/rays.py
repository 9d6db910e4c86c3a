"""Per-intrinsics cache of the pixel ray directions (recomputed every frame otherwise)."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ...camera import Intrinsics


@lru_cache(maxsize=16)
def ray_directions(intrinsics: Intrinsics) -> np.ndarray:
    """Read-only ``intrinsics.ray_directions()``: (H, W, 3) float64 unit rays, camera frame."""
    rays = intrinsics.ray_directions()
    rays.flags.writeable = False
    return rays
