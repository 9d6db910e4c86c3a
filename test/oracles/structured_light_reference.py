"""Step-by-step numpy versions of the structured-light scan and fusion: test oracles.

:func:`sl_scan_reference` renders the SL camera's image with the ray caster, then tests each
point's projector visibility (:func:`lit_by_projector`); the package's
:func:`~tof_mpd_ros.sim.structured_light.sl_scan` does all of it in one compiled pass
(:func:`~tof_mpd_ros.sim.raycast.sl_ranges`) and must give the same points bit for bit.
:func:`nearest_cluster_medians_reference` is the fusion's per-pixel cluster rule with one global
sort. Not shipped in the wheel (``test/``, importable as ``oracles.structured_light_reference``).

Units: millimetres and the robot base frame for points and poses; ranges are radial, mm.
"""

from __future__ import annotations

import math

import numpy as np

from oracles.raycast_reference import visible_from
from tof_mpd_ros.pose import invert_pose, make_pose, transform_points
from tof_mpd_ros.sim.raycast import camera_rays, render_surface
from tof_mpd_ros.sim.scene import Scene
from tof_mpd_ros.sim.structured_light import FusionConfig, StructuredLightConfig
from tof_mpd_ros.validation import check_array

_DEFAULT_SENSOR = StructuredLightConfig()


def lit_by_projector(scene: Scene, points_base: np.ndarray, sl_to_base_mm: np.ndarray,
                     sensor: StructuredLightConfig) -> np.ndarray:
    """(N,) bool: inside the projector's field of view and not occluded from it."""
    projector_to_base = sl_to_base_mm @ make_pose(np.eye(3), np.array(sensor.projector_in_sl_mm))
    local = transform_points(invert_pose(projector_to_base), points_base)
    intr = sensor.intrinsics
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = intr.project(local)
    in_view = ((local[:, 2] > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= intr.width - 0.5)
               & (uv[:, 1] >= -0.5) & (uv[:, 1] <= intr.height - 0.5))
    return in_view & visible_from(scene, points_base, projector_to_base[:3, 3],
                                  sensor.occlusion_tol_mm)


def sl_scan_reference(scene: Scene, sl_to_base_mm: np.ndarray, rng: np.random.Generator,
                      sensor: StructuredLightConfig = _DEFAULT_SENSOR) -> np.ndarray:
    """:func:`~tof_mpd_ros.sim.structured_light.sl_scan` step by step in numpy (ray cast
    image, then projector visibility): its test oracle.

    Args:
        scene: the scene (base frame, mm).
        sl_to_base_mm: (4, 4) SL camera optical frame -> base frame, mm.
        rng: source of the range noise.
        sensor: the SL sensor.

    Returns:
        (N, 3) float64 measured points in the base frame, mm (one per measured SL pixel).
    """
    pose = check_array("sl_to_base_mm", sl_to_base_mm, ndim=2, shape=(4, 4), dtype_kind="fiu")
    surface = render_surface(scene, pose, sensor.intrinsics)
    rays = camera_rays(sensor.intrinsics)
    ranges = surface.range_mm.reshape(-1)
    cos_incidence = -np.einsum("ij,ij->i", surface.normal.reshape(-1, 3), rays)
    seen = np.isfinite(ranges) & (cos_incidence >= math.cos(math.radians(sensor.max_incidence_deg)))
    rays, ranges = rays[seen], ranges[seen]
    points = transform_points(pose, rays * ranges[:, None])
    lit = lit_by_projector(scene, points, pose, sensor)
    noisy = ranges[lit] + rng.normal(0.0, sensor.noise_mm, size=int(lit.sum()))
    return transform_points(pose, rays[lit] * noisy[:, None])


def nearest_cluster_medians_reference(pixel: np.ndarray, range_mm: np.ndarray,
                                      fusion: FusionConfig) -> tuple[np.ndarray, np.ndarray]:
    """``structured_light._nearest_cluster_medians`` with one global numpy sort: its oracle.

    Args:
        pixel: (N,) int64 flat pixel index of each point; range_mm: (N,) float64 ranges, mm.

    Returns:
        (pixels (M,) int64, medians (M,) float64 mm), in increasing pixel order.
    """
    order = np.lexsort((range_mm, pixel))
    pix, rng_sorted = pixel[order], range_mm[order]
    breaks = np.empty(pix.size, dtype=bool)
    breaks[0] = True
    breaks[1:] = (pix[1:] != pix[:-1]) | (np.diff(rng_sorted) > fusion.cluster_gap_mm)
    starts = np.flatnonzero(breaks)
    sizes = np.diff(np.append(starts, pix.size))
    keep = sizes >= fusion.min_points
    starts, sizes = starts[keep], sizes[keep]
    cluster_pix = pix[starts]
    # Clusters are ordered by pixel, then range: the first kept one of a pixel is its nearest.
    first = np.ones(starts.size, dtype=bool)
    first[1:] = cluster_pix[1:] != cluster_pix[:-1]
    starts, sizes = starts[first], sizes[first]
    medians = 0.5 * (rng_sorted[starts + (sizes - 1) // 2] + rng_sorted[starts + sizes // 2])
    return cluster_pix[first], medians
