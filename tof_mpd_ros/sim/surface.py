"""What a camera ray hits: the interface between scene geometry and sensor physics.

The ray caster (:mod:`tof_mpd_ros.sim.raycast`) produces a :class:`SurfaceImage` for a camera
pose; the ToF physics (:mod:`tof_mpd_ros.sim.tof`) turns it into a measurement. A surface image
can also be derived from a reference range image alone (normals from the range gradient), which is
how the simulator predicts a real frame from its structured-light reference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import Intrinsics
from ..validation import check_array


@dataclass
class SurfaceImage:
    """Per-sample surface seen along each ray of a (possibly supersampled) image grid.

    Attributes:
        range_mm: (H, W) float64 radial range from the optical centre in mm; NaN = no hit.
        normal: (H, W, 3) float64 unit surface normals in the camera optical frame, oriented
            towards the camera (dot(normal, ray) <= 0); NaN where there is no hit.
        albedo: (H, W) float64 diffuse reflectance in [0, 1] at the near-infrared wavelength.
        object_id: (H, W) int32: 0 = table, k > 0 = k-th object, -1 = no hit.
        material_id: (H, W) int32 material index (0 = default), used by effects such as
            subsurface scattering; -1 = no hit.
        intrinsics: intrinsics of this H x W grid (``Intrinsics.scaled(s)`` when supersampled).
    """

    range_mm: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray
    object_id: np.ndarray
    material_id: np.ndarray
    intrinsics: Intrinsics

    def __post_init__(self) -> None:
        shape = self.intrinsics.shape
        self.range_mm = check_array("range_mm", self.range_mm, ndim=2, shape=shape,
                                    dtype_kind="fiu").astype(np.float64, copy=False)
        self.normal = check_array("normal", self.normal, ndim=3, shape=(*shape, 3),
                                  dtype_kind="f").astype(np.float64, copy=False)
        self.albedo = check_array("albedo", self.albedo, ndim=2, shape=shape,
                                  dtype_kind="fiu").astype(np.float64, copy=False)
        self.object_id = check_array("object_id", self.object_id, ndim=2, shape=shape,
                                     dtype_kind="iu").astype(np.int32, copy=False)
        self.material_id = check_array("material_id", self.material_id, ndim=2, shape=shape,
                                       dtype_kind="iu").astype(np.int32, copy=False)

    @property
    def valid(self) -> np.ndarray:
        """(H, W) bool: the ray hit a surface."""
        return np.isfinite(self.range_mm)

    def points_mm(self) -> np.ndarray:
        """(H, W, 3) float64 hit points in the camera optical frame, mm (NaN = no hit)."""
        return self.intrinsics.ray_directions() * self.range_mm[..., None]
