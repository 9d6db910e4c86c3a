"""Re-render a surface image from a slightly moved camera (pose errors of the ToF camera).

Used by the ``hand_eye`` and ``time_offset`` effects: the geometry the camera really saw differs
from the reference by a small rigid motion, so the reference is reprojected. The warp is a
backward map found by fixed-point iteration (each output pixel looks up the source sample that
lands on it), which leaves no cracks; output pixels that no source sample reaches within half a
pixel (disocclusions, outside the source image) become holes.
"""

from __future__ import annotations

import numpy as np

from ...pose import rotvec_to_matrix
from ..surface import SurfaceImage


def move_camera(surface: SurfaceImage, rotvec: np.ndarray, translation_mm: np.ndarray,
                iterations: int = 4) -> SurfaceImage:
    """The surface as seen by the camera moved by (R, t) relative to the original camera.

    Args:
        surface: surface image in the original camera frame.
        rotvec: (3,) rotation vector (rad) of the new camera in the original frame.
        translation_mm: (3,) position of the new optical centre in the original frame, mm.
        iterations: fixed-point iterations of the backward map.

    Returns:
        SurfaceImage on the same grid, in the new camera's frame: ``p' = Rᵀ (p − t)``.
    """
    rot = rotvec_to_matrix(rotvec)
    t = np.asarray(translation_mm, dtype=np.float64)
    k = surface.intrinsics
    h, w = k.shape
    pts = surface.points_mm() - t
    moved = pts @ rot  # row-vector form of Rᵀ (p − t)
    uv_new = k.project(moved)
    v0, u0 = np.mgrid[0:h, 0:w].astype(np.float64)
    # flow of each source sample; the output pixel (u0, v0) is fed by the source s with
    # s + flow(s) = (u0, v0): iterate s = (u0, v0) − flow(s) (holes have no flow: stay put)
    flow_u = np.nan_to_num(uv_new[..., 0] - u0)
    flow_v = np.nan_to_num(uv_new[..., 1] - v0)
    su, sv = u0.copy(), v0.copy()
    for _ in range(iterations):
        iu = np.clip(np.rint(su), 0, w - 1).astype(np.intp)
        iv = np.clip(np.rint(sv), 0, h - 1).astype(np.intp)
        su = u0 - flow_u[iv, iu]
        sv = v0 - flow_v[iv, iu]
    inside = (su > -0.5) & (su < w - 0.5) & (sv > -0.5) & (sv < h - 0.5)
    iu = np.clip(np.rint(su), 0, w - 1).astype(np.intp)
    iv = np.clip(np.rint(sv), 0, h - 1).astype(np.intp)
    land = uv_new[iv, iu]
    close = np.hypot(land[..., 0] - u0, land[..., 1] - v0) <= 0.75
    ok = inside & close & np.isfinite(land[..., 0])
    rng = np.where(ok, np.linalg.norm(moved[iv, iu], axis=-1), np.nan)
    normal = np.where(ok[..., None], surface.normal[iv, iu] @ rot, np.nan)
    return SurfaceImage(range_mm=rng, normal=normal,
                        albedo=np.where(ok, surface.albedo[iv, iu], 0.0),
                        object_id=np.where(ok, surface.object_id[iv, iu], -1),
                        material_id=np.where(ok, surface.material_id[iv, iu], -1),
                        intrinsics=k)
