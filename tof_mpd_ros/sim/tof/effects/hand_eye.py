"""``hand_eye``: the camera is not where the hand–eye calibration says.

The true camera pose differs from the assumed one by a small rotation (rx, ry, rz) and translation
(tx, ty, tz), both expressed in the assumed camera's optical frame. The scene (the reference) is
re-rendered from the true pose (:func:`..warp.move_camera`), so the error shows as an image shift
plus a range change that vary with the scene depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..context import RenderContext
from ..effect import CameraMoveEffect, param


@dataclass(frozen=True)
class HandEyeParams:
    """Parameters of :class:`HandEye`."""

    rx_mrad: float = param(0.0, -20.0, 20.0, "mrad", "rotation about the optical x axis")
    ry_mrad: float = param(0.0, -20.0, 20.0, "mrad", "rotation about the optical y axis")
    rz_mrad: float = param(0.0, -20.0, 20.0, "mrad", "rotation about the optical axis")
    tx_mm: float = param(0.0, -10.0, 10.0, "mm", "translation along optical x (right)")
    ty_mm: float = param(0.0, -10.0, 10.0, "mm", "translation along optical y (down)")
    tz_mm: float = param(0.0, -10.0, 10.0, "mm", "translation along the optical axis")


class HandEye(CameraMoveEffect):
    name = "hand_eye"
    summary = "small rotation/translation error of the camera pose; geometry reprojected"
    Params = HandEyeParams

    def camera_move(self, params: HandEyeParams, ctx: RenderContext
                    ) -> tuple[np.ndarray, np.ndarray]:
        """The calibration error itself, whatever the camera's motion (zero when at rest)."""
        rot = 1e-3 * np.array([params.rx_mrad, params.ry_mrad, params.rz_mrad], float)
        return rot, np.array([params.tx_mm, params.ty_mm, params.tz_mm], float)
