"""The structured-light (SL) reference sensor and the paper's multi-scan fusion.

The SL sensor is a camera and a projector 75 mm apart (the baseline). A surface point is measured
only if the camera sees it, the projector lights it (no occluder between them, inside the
projector's field of view) and the camera does not see it at too grazing an angle; its range
along the camera ray carries Gaussian noise (0.5 mm by default). Occlusion therefore leaves holes
on the projector's far side of every object, as in the paper.

To fill those holes the paper scans each ToF viewpoint with the SL sensor at 10 in-plane
rotations x 3 distances, transforms all points into the ToF camera frame, and per ToF pixel takes
the median range of the cluster of projected points nearest the camera; pixels with too few
points are missing (NaN). :func:`reference_range` does all of it.

Units: millimetres and the robot base frame for points and poses (``*_to_base_mm``: camera
optical frame -> base frame, translation in mm); ranges are *radial* ranges in mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba as nb
import numpy as np

from ..arm.tool import default_sl_to_tof_mm
from ..camera import Intrinsics
from ..errors import InputError
from ..pose import invert_pose, make_pose, rot_z, transform_points
from ..validation import check_array
from .raycast import camera_rays, sl_ranges
from .scene import Scene


@dataclass(frozen=True, eq=False)
class StructuredLightConfig:
    """The SL sensor.

    Attributes:
        intrinsics: the SL camera's image grid (also the projector's pattern grid).
        sl_to_tof_mm: (4, 4) SL camera optical frame -> ToF camera optical frame, mm (the
            hand-eye calibration between the two sensors).
        projector_in_sl_mm: (x, y, z) of the projector centre in the SL camera frame, mm; its
            norm is the baseline. The default puts it 75 mm further from the ToF camera. The
            projector looks along the SL camera's optical axis with the SL intrinsics.
        noise_mm: standard deviation of the range noise along the camera ray, mm.
        max_incidence_deg: surfaces seen more obliquely than this are not measured, degrees.
        occlusion_tol_mm: tolerance of the projector visibility test, mm.
    """

    intrinsics: Intrinsics = field(default_factory=lambda: Intrinsics.from_fov(240, 180, 65.0))
    sl_to_tof_mm: np.ndarray = field(default_factory=default_sl_to_tof_mm)
    projector_in_sl_mm: tuple[float, float, float] = (-75.0, 0.0, 0.0)
    noise_mm: float = 0.5
    max_incidence_deg: float = 80.0
    occlusion_tol_mm: float = 1.0


@dataclass(frozen=True)
class FusionConfig:
    """The multi-scan fusion of the paper.

    Attributes:
        n_rotations: in-plane rotations of the sensor about the ToF optical axis per distance,
            evenly spaced over 360 degrees.
        distance_offsets_mm: moves of the sensor along the ToF optical axis (positive = towards
            the scene), one set of rotations each.
        cluster_gap_mm: projected points of one pixel whose sorted ranges jump by more than this
            start a new cluster, mm.
        min_points: a cluster needs this many points; a pixel without such a cluster is NaN.
    """

    n_rotations: int = 10
    distance_offsets_mm: tuple[float, ...] = (-40.0, 0.0, 40.0)
    cluster_gap_mm: float = 3.0
    min_points: int = 5


def scan_poses(tof_to_base_mm: np.ndarray, sensor: StructuredLightConfig = StructuredLightConfig(),
               fusion: FusionConfig = FusionConfig()) -> np.ndarray:
    """Poses of the SL camera for the scans fused into one ToF viewpoint.

    The tool is turned about the ToF optical axis and moved along it, so the SL camera (offset
    by the hand-eye transform) circles the ToF viewpoint and its projector's shadows fall in
    every direction.

    Args:
        tof_to_base_mm: (4, 4) ToF camera optical frame -> base frame, mm.

    Returns:
        (n_rotations * len(distance_offsets_mm), 4, 4) float64 SL camera -> base poses, mm.
    """
    tof = check_array("tof_to_base_mm", tof_to_base_mm, ndim=2, shape=(4, 4), dtype_kind="fiu")
    poses = []
    for offset in fusion.distance_offsets_mm:
        for k in range(fusion.n_rotations):
            turn = make_pose(rot_z(2.0 * math.pi * k / fusion.n_rotations),
                             np.array([0.0, 0.0, offset]))
            poses.append(tof @ turn @ sensor.sl_to_tof_mm)
    return np.array(poses)


def sl_scan(scene: Scene, sl_to_base_mm: np.ndarray, rng: np.random.Generator,
            sensor: StructuredLightConfig = StructuredLightConfig()) -> np.ndarray:
    """One SL scan: noisy 3-D points of the surfaces both the camera and the projector see.

    The camera ray cast, incidence test and projector visibility run as one compiled pass
    (:func:`~tof_mpd_ros.sim.raycast.sl_ranges`); the result is that of the step-by-step
    numpy oracle ``test/oracles/structured_light_reference.py`` (the same ranges bit for bit,
    the same noise draws). The package's one implementation of an SL scan.

    Args:
        scene: the scene (base frame, mm).
        sl_to_base_mm: (4, 4) SL camera optical frame -> base frame, mm.
        rng: source of the range noise.
        sensor: the SL sensor.

    Returns:
        (N, 3) float64 measured points in the base frame, mm (one per measured SL pixel).
    """
    pose = check_array("sl_to_base_mm", sl_to_base_mm, ndim=2, shape=(4, 4), dtype_kind="fiu")
    projector_to_base = pose @ make_pose(np.eye(3), np.array(sensor.projector_in_sl_mm))
    ranges = sl_ranges(scene, pose, sensor.intrinsics, projector_to_base,
                       max_incidence_deg=sensor.max_incidence_deg,
                       tol_mm=sensor.occlusion_tol_mm)
    lit = np.isfinite(ranges)
    noisy = ranges[lit] + rng.normal(0.0, sensor.noise_mm, size=int(lit.sum()))
    return transform_points(pose, camera_rays(sensor.intrinsics)[lit] * noisy[:, None])


def fuse_points(points_base_mm: np.ndarray, tof_to_base_mm: np.ndarray, intrinsics: Intrinsics,
                fusion: FusionConfig = FusionConfig()) -> np.ndarray:
    """Reference radial range per ToF pixel from fused 3-D points (the paper's rule).

    Each point goes to the ToF pixel whose centre it projects nearest to. Per pixel the points
    are sorted by range and split into clusters where consecutive ranges jump by more than
    ``fusion.cluster_gap_mm``; clusters with fewer than ``fusion.min_points`` points are
    ignored; the pixel's value is the median range of its nearest remaining cluster.

    Away from depth discontinuities this recovers the range at the pixel centre (0.5 mm noise
    averaged over ~20 points). At a discontinuity the nearest cluster may be the foreground
    that covers only part of the pixel, so the reference takes the foreground side up to about
    half a pixel beyond the true edge: the paper's rule, kept on purpose.

    Args:
        points_base_mm: (N, 3) float points in the base frame, mm.
        tof_to_base_mm: (4, 4) ToF camera optical frame -> base frame, mm.
        intrinsics: the ToF image grid (e.g. the 180x140 crop).

    Returns:
        (H, W) float32 reference radial range in mm, NaN = missing.
    """
    pts = check_array("points_base_mm", points_base_mm, ndim=2, shape=(None, 3), dtype_kind="f")
    if fusion.min_points < 1:
        raise InputError(f"min_points must be >= 1, got {fusion.min_points}")
    to_tof = invert_pose(np.asarray(tof_to_base_mm, dtype=np.float64))
    k = intrinsics
    pixel, rng_mm = _project_kernel(np.ascontiguousarray(pts, dtype=np.float64),
                                    np.ascontiguousarray(to_tof[:3, :3]),
                                    np.ascontiguousarray(to_tof[:3, 3]), k.fx, k.fy, k.cx, k.cy,
                                    k.width, k.height)
    inside = pixel >= 0
    pixel, rng_mm = pixel[inside], rng_mm[inside]
    out = np.full(intrinsics.height * intrinsics.width, np.nan, dtype=np.float32)
    if pixel.size:
        pixels, medians = _nearest_cluster_medians(pixel, rng_mm, fusion)
        out[pixels] = medians
    return out.reshape(intrinsics.shape)


@nb.njit(parallel=True, cache=True)
def _project_kernel(points, rot, trans, fx, fy, cx, cy, width, height):  # pragma: no cover
    """Nearest ToF pixel (flat index, -1 = behind the camera or outside the image) and radial
    range (mm) of each base-frame point; ``rot``, ``trans``: base -> ToF camera frame."""
    n = points.shape[0]
    pixel = np.full(n, -1, dtype=np.int64)
    range_mm = np.zeros(n)
    for i in nb.prange(n):
        px = points[i, 0]
        py = points[i, 1]
        pz = points[i, 2]
        x = rot[0, 0] * px + rot[0, 1] * py + rot[0, 2] * pz + trans[0]
        y = rot[1, 0] * px + rot[1, 1] * py + rot[1, 2] * pz + trans[1]
        z = rot[2, 0] * px + rot[2, 1] * py + rot[2, 2] * pz + trans[2]
        if not z > 0.0:
            continue
        u = np.rint(fx * x / z + cx)
        v = np.rint(fy * y / z + cy)
        if u >= 0.0 and u < width and v >= 0.0 and v < height:
            pixel[i] = int(v) * width + int(u)
            range_mm[i] = math.sqrt(x * x + y * y + z * z)
    return pixel, range_mm


@nb.njit(cache=True)
def _cluster_kernel(pixel, range_mm, n_pixels, gap_mm, min_points):  # pragma: no cover
    """Median of the nearest cluster per pixel (NaN = none): bucket by pixel, sort each bucket."""
    counts = np.zeros(n_pixels + 1, dtype=np.int64)
    for p in pixel:
        counts[p + 1] += 1
    start = np.cumsum(counts)
    fill = start[:-1].copy()
    bucket = np.empty(range_mm.size)
    for i in range(pixel.size):
        bucket[fill[pixel[i]]] = range_mm[i]
        fill[pixel[i]] += 1
    out = np.full(n_pixels, np.nan)
    for p in range(n_pixels):
        lo = start[p]
        hi = start[p + 1]
        if hi - lo < min_points:
            continue
        vals = np.sort(bucket[lo:hi])
        first = 0
        for j in range(1, vals.size + 1):
            if j == vals.size or vals[j] - vals[j - 1] > gap_mm:
                size = j - first
                if size >= min_points:
                    out[p] = 0.5 * (vals[first + (size - 1) // 2] + vals[first + size // 2])
                    break
                first = j
    return out


def _nearest_cluster_medians(pixel: np.ndarray, range_mm: np.ndarray,
                             fusion: FusionConfig) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel, the median range of the nearest cluster with enough points.

    Points are bucketed by pixel (a counting sort) and each pixel's few ranges sorted, in one
    compiled pass; the result is identical to the global-sort oracle
    (``test/oracles/structured_light_reference.py``).

    Args:
        pixel: (N,) int64 flat pixel index of each point; range_mm: (N,) float64 ranges, mm.

    Returns:
        (pixels (M,) int64, medians (M,) float64 mm) for the M pixels that have a cluster, in
        increasing pixel order.
    """
    pixel = np.ascontiguousarray(pixel, dtype=np.int64)
    n_pixels = int(pixel.max()) + 1 if pixel.size else 0
    medians = _cluster_kernel(pixel, np.ascontiguousarray(range_mm, dtype=np.float64),
                              n_pixels, float(fusion.cluster_gap_mm), int(fusion.min_points))
    pixels = np.flatnonzero(np.isfinite(medians))
    return pixels, medians[pixels]


def reference_range(scene: Scene, tof_to_base_mm: np.ndarray, intrinsics: Intrinsics,
                    rng: np.random.Generator,
                    sensor: StructuredLightConfig = StructuredLightConfig(),
                    fusion: FusionConfig = FusionConfig()) -> np.ndarray:
    """The fused SL reference for one ToF viewpoint: scan at every pose, then fuse.

    Args:
        scene: the scene (base frame, mm).
        tof_to_base_mm: (4, 4) ToF camera optical frame -> base frame, mm.
        intrinsics: the ToF image grid of the reference.
        rng: source of the SL noise.

    Returns:
        (H, W) float32 reference radial range in mm in the ToF frame, NaN = missing.
    """
    poses = scan_poses(tof_to_base_mm, sensor, fusion)
    points = np.concatenate([sl_scan(scene, pose, rng, sensor) for pose in poses])
    return fuse_points(points, tof_to_base_mm, intrinsics, fusion)
