"""Analytic scenes of convex polyhedra: an exact ray caster for the tests (not shipped).

A tiny exact ray caster: each solid is an intersection of half-spaces ``n·p <= c`` (``n`` the
outward unit normal, camera frame, mm); a scene is a union of solids. The first point where a
camera ray enters any solid is the visible surface and the entering face gives its normal. This
is independent of the cell's mesh ray caster and gives exact normals for physics checks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.sim.surface import SurfaceImage


@dataclass(frozen=True)
class ConvexSolid:
    """Intersection of half-spaces ``normals @ p <= offsets``.

    Attributes:
        normals: (K, 3) float64 outward unit normals in the camera frame.
        offsets: (K,) float64 offsets in mm.
        albedo: diffuse reflectance in [0, 1].
        material: material index (subsurface).
    """

    normals: np.ndarray
    offsets: np.ndarray
    albedo: float = 0.5
    material: int = 0


def half_space(normal: tuple[float, float, float], point: tuple[float, float, float],
               albedo: float = 0.5, material: int = 0) -> ConvexSolid:
    """The solid behind the plane through ``point`` whose outward normal is ``normal``."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    return ConvexSolid(n[None, :], np.array([n @ np.asarray(point, dtype=np.float64)]),
                       albedo, material)


def box(lo: tuple[float, float, float], hi: tuple[float, float, float], albedo: float = 0.5,
        material: int = 0) -> ConvexSolid:
    """Axis-aligned box between corners ``lo`` and ``hi`` (mm, camera frame)."""
    normals = np.vstack([np.eye(3), -np.eye(3)])
    offsets = np.concatenate([np.asarray(hi, float), -np.asarray(lo, float)])
    return ConvexSolid(normals, offsets, albedo, material)


def raycast(solids: list[ConvexSolid], intrinsics: Intrinsics) -> SurfaceImage:
    """Surface image of a union of convex solids seen from the camera at the origin."""
    rays = intrinsics.ray_directions()
    h, w = intrinsics.shape
    best = np.full((h, w), np.inf)
    normal = np.full((h, w, 3), np.nan)
    albedo = np.zeros((h, w))
    obj = np.full((h, w), -1, np.int32)
    mat = np.full((h, w), -1, np.int32)
    for index, solid in enumerate(solids):
        nd = rays @ solid.normals.T  # (H, W, K)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = solid.offsets / nd
        entering = nd < 0
        t_in = np.where(entering, t, -np.inf)
        enter = t_in.max(axis=-1)
        face = t_in.argmax(axis=-1)
        exit_ = np.where(nd > 0, t, np.inf).min(axis=-1)
        # rays parallel to a face miss unless the camera is on its inner side
        parallel_out = ((nd == 0) & (solid.offsets < 0)).any(axis=-1)
        hit = entering.any(axis=-1) & (enter > 0) & (enter <= exit_) & ~parallel_out
        closer = hit & (enter < best)
        best = np.where(closer, enter, best)
        normal[closer] = solid.normals[face[closer]]
        albedo[closer] = solid.albedo
        obj[closer] = index
        mat[closer] = solid.material
    return SurfaceImage(range_mm=np.where(np.isfinite(best), best, np.nan), normal=normal,
                        albedo=albedo, object_id=obj, material_id=mat, intrinsics=intrinsics)


def plane_scene(distance_mm: float = 300.0, albedo: float = 0.5,
                tilt_rad: float = 0.0) -> list[ConvexSolid]:
    """A lone plane at ``distance_mm`` along the optical axis, tilted about the y axis."""
    n = (np.sin(tilt_rad), 0.0, -np.cos(tilt_rad))
    return [half_space(n, (0.0, 0.0, distance_mm), albedo)]


def groove_scene(distance_mm: float = 300.0, albedo: float = 0.5) -> list[ConvexSolid]:
    """Two perpendicular planes forming a concave 90° groove along y, crease on the optical
    axis at ``distance_mm``, each plane at 45° to the axis."""
    crease = (0.0, 0.0, distance_mm)
    return [half_space((1.0, 0.0, -1.0), crease, albedo),
            half_space((-1.0, 0.0, -1.0), crease, albedo)]


def box_on_table_scene(table_mm: float = 300.0, height_mm: float = 100.0,
                       wall_x_mm: float = 40.0, albedo: float = 0.5,
                       box_albedo: float | None = None) -> list[ConvexSolid]:
    """A table facing the camera at ``table_mm`` and a box standing on it whose left face
    (normal −x) is the plane x = ``wall_x_mm``: a concave crease where face meets table."""
    top = table_mm - height_mm
    return [half_space((0.0, 0.0, -1.0), (0.0, 0.0, table_mm), albedo),
            box((wall_x_mm, -1e4, top), (1e4, 1e4, table_mm + 1.0),
                albedo if box_albedo is None else box_albedo, material=1)]
