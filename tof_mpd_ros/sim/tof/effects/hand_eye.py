"""``hand_eye``: the camera is not where the hand–eye calibration says.

The true camera pose differs from the assumed one by a small rotation (rx, ry, rz) and translation
(tx, ty, tz), both expressed in the assumed camera's optical frame. The scene (the reference) is
re-rendered from the true pose (:func:`..warp.move_camera`), so the error shows as an image shift
plus a range change that vary with the scene depth.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ...surface import SurfaceImage
from ..context import RenderContext
from ..effect import Effect, ParamSpec
from ._geometry import moved_surface


class HandEye(Effect):
    name = "hand_eye"
    stage = "geometry"
    summary = "small rotation/translation error of the camera pose; geometry reprojected"
    params = (
        ParamSpec("rx_mrad", 0.0, -20.0, 20.0, "mrad", "rotation about the optical x axis"),
        ParamSpec("ry_mrad", 0.0, -20.0, 20.0, "mrad", "rotation about the optical y axis"),
        ParamSpec("rz_mrad", 0.0, -20.0, 20.0, "mrad", "rotation about the optical axis"),
        ParamSpec("tx_mm", 0.0, -10.0, 10.0, "mm", "translation along optical x (right)"),
        ParamSpec("ty_mm", 0.0, -10.0, 10.0, "mm", "translation along optical y (down)"),
        ParamSpec("tz_mm", 0.0, -10.0, 10.0, "mm", "translation along the optical axis"),
    )

    def apply(self, x: SurfaceImage, params: Mapping[str, Any],
              ctx: RenderContext) -> SurfaceImage:
        rot = 1e-3 * np.array([params["rx_mrad"], params["ry_mrad"], params["rz_mrad"]], float)
        trans = np.array([params["tx_mm"], params["ty_mm"], params["tz_mm"]], float)
        return moved_surface(x, rot, trans, ctx)
