"""Pinhole intrinsics, central crops and the radial-range / z-depth conversion.

Conventions used throughout the package:

* camera frame = ROS optical frame (REP 103): x right, y down, z forward, metres for poses;
* ``range_mm``: *radial* range, the distance from the optical centre to the surface point along
  the pixel's ray, in millimetres (what a ToF camera measures);
* ``depth_mm`` / ROS depth images: *z-depth*, the distance along the optical axis (REP 118).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace

import numpy as np

from .errors import InputError
from .validation import check_array

# SoftKinetic DS325-like ToF sensor: 320x240 with ~74 degrees horizontal field of view.
DS325_WIDTH = 320
DS325_HEIGHT = 240
DS325_HFOV_DEG = 74.0
# The paper processes the central 180x140 of the frame.
PAPER_CROP = (180, 140)


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of an image of ``width`` x ``height`` pixels (no distortion).

    ``fx, fy, cx, cy`` are in pixels of *this* image; pixel (u, v) has its centre at integer
    coordinates, so a centred principal point of a 320-wide image is ``cx = 159.5``.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        if not (self.fx > 0 and self.fy > 0 and self.width > 0 and self.height > 0):
            raise InputError(f"invalid intrinsics {self}: focal lengths and size must be > 0")
        if not all(math.isfinite(v) for v in (self.fx, self.fy, self.cx, self.cy)):
            raise InputError(f"invalid intrinsics {self}: values must be finite")

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float) -> Intrinsics:
        """Square pixels, centred principal point, horizontal field of view ``hfov_deg``."""
        f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(f, f, (width - 1) / 2.0, (height - 1) / 2.0, width, height)

    @classmethod
    def ds325(cls) -> Intrinsics:
        """The full 320x240 frame of a DS325-like sensor (~74 deg horizontal FOV)."""
        return cls.from_fov(DS325_WIDTH, DS325_HEIGHT, DS325_HFOV_DEG)

    @property
    def shape(self) -> tuple[int, int]:
        """``(height, width)``, the numpy shape of an image with these intrinsics."""
        return (self.height, self.width)

    def crop_window(self, width: int, height: int) -> tuple[slice, slice]:
        """Row and column slices of the central ``width`` x ``height`` window."""
        if not (0 < width <= self.width and 0 < height <= self.height):
            raise InputError(f"crop {width}x{height} does not fit in a "
                             f"{self.width}x{self.height} image")
        top = (self.height - height) // 2
        left = (self.width - width) // 2
        return slice(top, top + height), slice(left, left + width)

    def crop(self, width: int, height: int) -> Intrinsics:
        """Intrinsics of the central ``width`` x ``height`` window."""
        rows, cols = self.crop_window(width, height)
        return replace(self, cx=self.cx - cols.start, cy=self.cy - rows.start,
                       width=width, height=height)

    def expanded(self, margin_px: int) -> Intrinsics:
        """Intrinsics of the same camera with ``margin_px`` more pixels on every side (a virtual
        border: it may reach past the sensor, for rays that a renderer needs beyond it)."""
        m = int(margin_px)
        if m < 0:
            raise InputError(f"margin must be >= 0 px, got {margin_px}")
        return replace(self, cx=self.cx + m, cy=self.cy + m, width=self.width + 2 * m,
                       height=self.height + 2 * m)

    def scaled(self, factor: int) -> Intrinsics:
        """Intrinsics of the same view sampled ``factor`` times more finely per axis."""
        s = float(factor)
        return Intrinsics(self.fx * s, self.fy * s, (self.cx + 0.5) * s - 0.5,
                          (self.cy + 0.5) * s - 0.5, self.width * factor, self.height * factor)

    def ray_directions(self) -> np.ndarray:
        """Unit ray direction of every pixel centre.

        Returns:
            (H, W, 3) float64, unit vectors in the camera optical frame.
        """
        v, u = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
        rays = np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy,
                         np.ones_like(u)], axis=-1)
        return rays / np.linalg.norm(rays, axis=-1, keepdims=True)

    def z_per_radial(self) -> np.ndarray:
        """Cosine of each pixel's ray angle to the optical axis: ``depth = range * cos``.

        Returns:
            (H, W) float64 in (0, 1], read-only: computed once per distinct camera and
            shared (at 320x240 the rays cost ~5 ms, paid up to three times per corrected
            frame of a z-depth stream).
        """
        return _z_per_radial(self)

    def radial_to_z(self, range_mm: np.ndarray) -> np.ndarray:
        """Convert radial range to z-depth (same unit as the input, NaN stays NaN).

        Args:
            range_mm: (..., H, W) float radial range.

        Returns:
            (..., H, W) float32 z-depth.
        """
        r = check_array("range", range_mm, shape=self.shape, dtype_kind="fiu")
        return (r * self.z_per_radial()).astype(np.float32)

    def z_to_radial(self, depth_mm: np.ndarray) -> np.ndarray:
        """Convert z-depth to radial range (same unit as the input, NaN stays NaN).

        Args:
            depth_mm: (..., H, W) float z-depth.

        Returns:
            (..., H, W) float32 radial range.
        """
        d = check_array("depth", depth_mm, shape=self.shape, dtype_kind="fiu")
        return (d / self.z_per_radial()).astype(np.float32)

    def backproject(self, range_mm: np.ndarray) -> np.ndarray:
        """3-D points of a radial range image.

        Args:
            range_mm: (H, W) float radial range in mm (NaN = missing).

        Returns:
            (H, W, 3) float64 points in the camera optical frame, in mm (NaN where missing).
        """
        r = check_array("range_mm", range_mm, ndim=2, shape=self.shape, dtype_kind="fiu")
        return self.ray_directions() * r[..., None]

    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixel coordinates of 3-D points.

        Args:
            points: (..., 3) points in the camera optical frame (any length unit), z > 0.

        Returns:
            (..., 2) float64 ``(u, v)`` pixel coordinates.
        """
        p = np.asarray(points, dtype=np.float64)
        z = p[..., 2]
        return np.stack([self.fx * p[..., 0] / z + self.cx,
                         self.fy * p[..., 1] / z + self.cy], axis=-1)

    def as_dict(self) -> dict[str, float | int]:
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
                "width": self.width, "height": self.height}


@functools.lru_cache(maxsize=16)
def _z_per_radial(intrinsics: Intrinsics) -> np.ndarray:
    """:meth:`Intrinsics.z_per_radial` of one camera (the frozen dataclass is the key)."""
    cos = np.ascontiguousarray(intrinsics.ray_directions()[..., 2])
    cos.flags.writeable = False
    return cos
