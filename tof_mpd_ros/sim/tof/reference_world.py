"""A :class:`~.world.WorldModel` from range images alone (a reference, or a rendered surface).

What a range image gives: the surfaces its camera sees. What light transport also needs: every
surface the light reaches, most of it outside the image (the table in front of a box lights the
box's side face). This module fills in what can be inferred and states what cannot:

* **the support plane** — fitted robustly (RANSAC, then least squares on its inliers) and
  preferred over other planes when nothing lies behind it — is extended across the light's cone
  outside the image, with the albedo of its visible part;
* **surfaces cut by the image border** (a wall rising out of the frame, an object's face
  running past it) continue past the border on their own plane for a band of
  ``BORDER_FRACTION`` of the image: light from just outside the frame matters most, and
  what lies further out is unknown;
* **other views** of the same scene, placed by their poses, add the surfaces only they saw
  (the back of an object, table hidden behind it here); free space is what any view saw through
  (space carving), so each view also refines visibility;
* **unknowable** from images: surfaces no view saw (the far side of objects outside every
  view; objects outside every image stand where the plane is assumed free), the albedo of
  unseen surfaces (the plane's is used), anything below the support plane. These are assumed
  absent.

Units: mm; the world frame is the target camera's frame unless poses are given.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ...camera import Intrinsics
from ...errors import InputError
from ..surface import SurfaceImage
from .transport import shadow_test_views
from .world import (
    _NORMAL_BINS,
    DEFAULT_BEAM_DEG,
    DEFAULT_CUTOFF_DEG,
    DEFAULT_LEAF_MM,
    DepthViews,
    FaceGrid,
    HeightField,
    WorldModel,
    build_tree,
    camera_spot,
    depth_view,
    surface_faces,
)

#: the plane is extended at most this many camera distances from the camera
MAX_REACH = 4.0
#: a plane must hold this fraction of the valid pixels to be extended
MIN_PLANE_FRACTION = 0.1
#: surfaces cut by the image border continue past it by this fraction of the image's larger
#: side (see :func:`border_extension`)
BORDER_FRACTION = 0.15
#: a surface is continued past the border only where the rays meet it at least this steeply
#: (cosine of the incidence angle): a grazing plane would run off to far ranges
MIN_BORDER_COS = math.cos(math.radians(75.0))


@dataclass(frozen=True)
class ReferenceView:
    """Another reference image of the same scene, placed by its pose.

    Attributes:
        reference_mm: (H, W) float radial range in mm, NaN = missing.
        camera_to_world_mm: (4, 4) float64 camera optical frame → world, mm.
        albedo: (H, W) albedo, a scalar, or None (the default albedo).
    """

    reference_mm: np.ndarray
    camera_to_world_mm: np.ndarray
    albedo: np.ndarray | float | None = None


@dataclass(frozen=True)
class Plane:
    """A plane n·p = d (camera frame), n a unit vector pointing towards the camera.

    Attributes:
        normal: (3,) float64 unit normal, n·(0 − p) > 0 for the camera at the origin.
        offset_mm: d, so the camera's distance to the plane is −d.
        inlier_fraction: share of the valid pixels within tolerance of the plane.
    """

    normal: np.ndarray
    offset_mm: float
    inlier_fraction: float


def _tolerance(points: np.ndarray) -> np.ndarray:
    return 2.0 + 0.005 * np.linalg.norm(points, axis=-1)


def fit_support_plane(points_mm: np.ndarray, *, iterations: int = 256, seed: int = 0,
                      up: np.ndarray | None = None, max_tilt_deg: float = 25.0) -> Plane | None:
    """The plane the scene stands on: many inliers and (almost) nothing behind it.

    Without ``up`` a wall that fills more of the image than the table can win; with the
    camera's pose the robot knows which way is up, and only planes within ``max_tilt_deg`` of
    horizontal are candidates.

    Args:
        points_mm: (N, 3) float64 visible points, camera frame, mm (NaN rows ignored).
        iterations: RANSAC hypotheses.
        seed: sampling seed (the fit is deterministic).
        up: (3,) unit vector pointing up (against gravity) in the camera frame, or None.
        max_tilt_deg: largest angle between a candidate's normal and ``up``.

    Returns:
        The plane, or None when no plane holds ``MIN_PLANE_FRACTION`` of the points.
    """
    p = points_mm[np.all(np.isfinite(points_mm), axis=1)]
    if p.shape[0] < 50:
        return None
    rng = np.random.default_rng(seed)
    sub = p[rng.choice(p.shape[0], size=min(p.shape[0], 4000), replace=False)]
    tol = _tolerance(sub)
    tri = sub[rng.integers(0, sub.shape[0], size=(iterations, 3))]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(n, axis=1)
    ok = norm > 1e-9
    n = n[ok] / norm[ok, None]
    d = np.einsum("ij,ij->i", n, tri[ok, 0])
    # orient towards the camera (origin): n·(0 − p) > 0  <=>  d < 0
    flip = d > 0
    n[flip] *= -1
    d[flip] *= -1
    signed = sub @ n.T - d  # (M, H) > 0: in front of the plane (camera side)
    inliers = np.abs(signed) <= tol[:, None]
    behind = signed < -tol[:, None]
    # a support plane has the scene in front of it: points behind it count against it
    score = inliers.sum(axis=0) - 4 * behind.sum(axis=0)
    if up is not None:
        score = np.where(n @ np.asarray(up, float) >= np.cos(np.radians(max_tilt_deg)), score,
                         -np.inf)
        if not np.isfinite(score).any():
            return None
    best = int(np.argmax(score))
    if inliers[:, best].mean() < MIN_PLANE_FRACTION:
        return None
    normal, offset = _refine(p, n[best], d[best])
    frac = float((np.abs(p @ normal - offset) <= _tolerance(p)).mean())
    if frac < MIN_PLANE_FRACTION:
        return None
    return Plane(normal, offset, frac)


def _refine(points: np.ndarray, n: np.ndarray, d: float) -> tuple[np.ndarray, float]:
    """Least-squares plane through the inliers of (n, d), twice."""
    for _ in range(2):
        close = np.abs(points @ n - d) <= _tolerance(points)
        q = points[close]
        c = q.mean(axis=0)
        n_new = np.linalg.svd(q - c, full_matrices=False)[2][-1]
        if n_new @ n < 0:
            n_new = -n_new
        n, d = n_new, float(n_new @ c)
    return n, d


def _plane_face(plane: Plane, albedo: float, leaf_mm: float, cutoff_deg: float) -> FaceGrid:
    """Leaves of the plane across the light's cone (camera frame; light at the origin, +z)."""
    n, d = plane.normal, plane.offset_mm
    foot = n * d                      # nearest plane point to the camera
    reach = MAX_REACH * max(-d, 1.0)
    # in-plane axes, the first as close to the image x axis as possible
    e1 = np.array([1.0, 0.0, 0.0]) - n[0] * n
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    ang = np.radians(min(cutoff_deg, 89.0))
    phi = np.linspace(0, 2 * np.pi, 72, endpoint=False)
    dirs = np.stack([np.sin(ang) * np.cos(phi), np.sin(ang) * np.sin(phi),
                     np.full_like(phi, np.cos(ang))], axis=1)
    dirs = np.vstack([dirs, [0.0, 0.0, 1.0]])
    along = dirs @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(along < 0, d / along, np.inf)
    pts = dirs * np.minimum(t, reach)[:, None]
    uv = np.clip(np.stack([(pts - foot) @ e1, (pts - foot) @ e2], axis=1), -reach, reach)
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    nu = max(1, int(np.ceil((hi[0] - lo[0]) / leaf_mm)))
    nv = max(1, int(np.ceil((hi[1] - lo[1]) / leaf_mm)))
    gu, gv = np.meshgrid(lo[0] + (np.arange(nu) + 0.5) * (hi[0] - lo[0]) / nu,
                         lo[1] + (np.arange(nv) + 0.5) * (hi[1] - lo[1]) / nv, indexing="ij")
    centre = foot + gu[..., None] * e1 + gv[..., None] * e2
    cos_axis = centre[..., 2] / np.linalg.norm(centre, axis=-1)
    valid = cos_axis >= np.cos(np.radians(cutoff_deg))
    area = np.full((nu, nv), (hi[0] - lo[0]) * (hi[1] - lo[1]) / (nu * nv))
    return FaceGrid(centre, np.broadcast_to(n, centre.shape).copy(), area,
                    np.full((nu, nv), float(albedo)), valid,
                    ((hi[0] - lo[0]) / nu, (hi[1] - lo[1]) / nv))


def view_lookup(points: np.ndarray, world_to_camera: np.ndarray, kin: np.ndarray,
                range_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where world points fall in a view: their own range, and the view's range there.

    Args:
        points: (..., 3) float64 world points, mm.
        world_to_camera: (3, 4) float64 world → camera, mm.
        kin: (4,) fx, fy, cx, cy of the view (px).
        range_mm: (H, W) the view's radial range (NaN or inf = missing).

    Returns:
        (...) float64 the points' range from the view's camera, mm; (...) float64 the view's
        range at the nearest pixel, NaN where the point is behind the camera or off the image.
    """
    c = points @ world_to_camera[:, :3].T + world_to_camera[:, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.rint(kin[0] * c[..., 0] / c[..., 2] + kin[2])
        v = np.rint(kin[1] * c[..., 1] / c[..., 2] + kin[3])
    h, w = range_mm.shape
    inside = (c[..., 2] > 0) & (u >= 0) & (v >= 0) & (u < w) & (v < h)
    there = range_mm[np.where(inside, v, 0).astype(int), np.where(inside, u, 0).astype(int)]
    return np.linalg.norm(c, axis=-1), np.where(inside, there, np.nan)


def _plane_axes(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit axes spanning the plane with normal ``n``."""
    e1 = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1)


def _closing_size(uv: np.ndarray, cell_mm: float) -> int:
    """Odd kernel size (cells) that closes the gaps between neighbouring points ``uv``
    (M, 2) mm: the 90th percentile of their nearest-neighbour spacing."""
    from scipy.spatial import cKDTree

    if len(uv) < 2:
        return 3
    spacing, _ = cKDTree(uv).query(uv, k=2)
    gap = float(np.percentile(spacing[:, 1], 90)) / cell_mm
    return max(3, 2 * math.ceil(0.5 * gap) + 1)


def _wall_runs(ci: np.ndarray, cj: np.ndarray, bins: np.ndarray,
               shape: tuple[int, int]) -> list[np.ndarray]:
    """The outline cells (``ci``, ``cj``) (C,) int split into runs: 8-connected cells whose
    outward normals share a direction bin ``bins`` (C,) int. Returns index arrays into C."""
    from scipy.ndimage import label

    grid = np.full(shape, -1, dtype=np.int64)
    grid[ci, cj] = bins
    runs = []
    for b in np.unique(bins):
        regions, _ = label(grid == b, structure=np.ones((3, 3), bool))
        region = regions[ci, cj]
        runs += [np.flatnonzero(region == r) for r in np.unique(region[bins == b])]
    return runs


def extruded_objects(world_plane: np.ndarray, points: np.ndarray, albedo: np.ndarray,
                     views: list, cell_mm: float, leaf_mm: float
                     ) -> tuple[HeightField | None, list[FaceGrid]]:
    """Objects standing on the support plane, extruded down to it: a height field for
    visibility, and leaves for their walls that no view sees (the far sides of objects).

    Every off-plane point becomes a column down to the plane; the columns' outline gets walls
    facing outwards (normals from the smoothed outline), cut into ``leaf_mm`` patches; walls
    that a view sees at their place are left out (the view's pixels are those surfaces).

    Args:
        world_plane: (4,) (n, d) of the plane, n·p = d, n towards the free side (world frame).
        points: (M, 3) off-plane surface points, world frame, mm.
        albedo: (M,) their albedo (the walls take the median).
        views: (world → camera (3, 4), fx fy cx cy (4,), range (H, W)) of every view.
        cell_mm: height-field cell, mm.
        leaf_mm: wall patch height, mm.

    Returns:
        The height field (None without off-plane points) and the walls' faces.
    """
    from scipy.ndimage import gaussian_filter

    columns = _height_columns(world_plane, points, cell_mm)
    if columns is None:
        return None, []
    heights, field, above = columns
    n, e1, e2, origin = field.normal, field.e1, field.e2, field.origin
    # the outline: occupied cells next to a free one; outward = down the smoothed occupancy
    inside = heights > 0
    pad = np.pad(inside, 1)
    edge = inside & ~(pad[:-2, 1:-1] & pad[2:, 1:-1] & pad[1:-1, :-2] & pad[1:-1, 2:])
    gu, gv = np.gradient(gaussian_filter(inside.astype(float), 1.0))
    ci, cj = np.nonzero(edge & (np.hypot(gu, gv) > 1e-6))
    if ci.size == 0:
        return field, []
    out_uv = -np.stack([gu[ci, cj], gv[ci, cj]], axis=1)
    out_uv /= np.linalg.norm(out_uv, axis=1, keepdims=True)
    normal = out_uv[:, :1] * e1 + out_uv[:, 1:] * e2
    base = origin + ((ci + 0.5)[:, None] * e1 + (cj + 0.5)[:, None] * e2) * cell_mm \
        + 0.5 * cell_mm * normal
    h = heights[ci, cj]
    k = np.maximum(1, np.ceil(h / leaf_mm)).astype(int)
    k_max = int(k.max())
    levels = (np.arange(k_max) + 0.5)[None, :] / k[:, None]             # (C, K) in (0, 1)
    valid = np.arange(k_max)[None, :] < k[:, None]
    centre = base[:, None, :] + (levels * h[:, None])[..., None] * n
    width = cell_mm / np.abs(out_uv).sum(axis=1)  # outline length a boundary cell stands for
    area = np.broadcast_to((width * h / k)[:, None], valid.shape).copy()
    hidden = valid.copy()
    for w2c, kin, depth in views:
        own, there = view_lookup(centre, w2c, kin, depth)
        # in front of (or on) what the view shows there: the view sees this wall itself
        with np.errstate(invalid="ignore"):
            hidden &= ~(np.isfinite(there) & (own <= there + 3.0 + 0.03 * there))
    rho = float(np.median(albedo[above]))
    faces = []
    for sel in _wall_runs(ci, cj, np.argmax(normal @ _NORMAL_BINS.T, axis=1), heights.shape):
        # a run's columns in order along it: grid neighbours are neighbours on the wall, so
        # the hierarchy merges them into patches (as it does an image's pixels)
        sel = sel[np.argsort((base[sel] - origin) @ np.cross(n, normal[sel[0]]))]
        faces.append(FaceGrid(centre[sel], np.broadcast_to(normal[sel][:, None, :],
                                                             centre[sel].shape).copy(),
                              area[sel], np.full(valid[sel].shape, rho),
                              valid[sel] & hidden[sel], (cell_mm, leaf_mm)))
    return field, faces


def _height_columns(world_plane: np.ndarray, points: np.ndarray, cell_mm: float
                    ) -> tuple[np.ndarray, HeightField, np.ndarray] | None:
    """The off-plane points as columns down to the support plane: their heights (U, V) mm on
    a ``cell_mm`` grid of the plane, the visibility height field (one cell inside the
    outline) and which of ``points`` (M,) bool are off the plane; None with too few."""
    from scipy.ndimage import grey_closing, grey_erosion

    n, d = world_plane[:3], float(world_plane[3])
    up = points @ n - d
    above = up > 1.5
    if above.sum() < 20:
        return None
    p, up = points[above], up[above]
    e1, e2 = _plane_axes(n)
    foot = n * d
    uv = np.stack([(p - foot) @ e1, (p - foot) @ e2], axis=1)
    lo = uv.min(axis=0) - 2 * cell_mm
    shape = tuple(np.ceil((uv.max(axis=0) + 2 * cell_mm - lo) / cell_mm).astype(int))
    ij = np.floor((uv - lo) / cell_mm).astype(int)
    heights = np.zeros(shape)
    np.maximum.at(heights, (ij[:, 0], ij[:, 1]), up)
    # points are splatted into single cells: close the gaps between them (coarse pixels far
    # from the camera are several cells apart; open gaps would each grow walls of their own)
    heights = grey_closing(heights, size=_closing_size(uv, cell_mm))
    origin = foot + lo[0] * e1 + lo[1] * e2
    # occupancy one cell inside the outline: a cell on it is partly free space, and a ray
    # grazing a visible face must not be cut by the cell the face runs through
    field = HeightField(origin, e1, e2, n.copy(), float(cell_mm), grey_erosion(heights, size=3))
    return heights, field, above


def plane_pixels(surface: SurfaceImage, plane: Plane, max_tilt_deg: float = 25.0) -> np.ndarray:
    """(H, W) bool pixels lying on ``plane`` (within tolerance) and facing like it."""
    points = surface.points_mm()
    close = np.abs(points @ plane.normal - plane.offset_mm) <= _tolerance(points)
    facing = np.nan_to_num(surface.normal @ plane.normal) >= np.cos(np.radians(max_tilt_deg))
    return close & facing & surface.valid


def border_extension(surface: SurfaceImage, margin_px: int,
                     plane: Plane | None = None) -> tuple[SurfaceImage, np.ndarray]:
    """The image widened by ``margin_px`` on every side, each border pixel's surface continued.

    A margin pixel takes the plane (point and normal) of its nearest image pixel and its ray
    is intersected with it. It stays empty where that pixel is missing or lies on the support
    plane (``plane``: represented exactly elsewhere), where the ray meets the continued plane
    at a grazing angle (``MIN_BORDER_COS``) or beyond twice the border pixel's range, and
    where the support plane is hit first.

    Args:
        surface: the range image's surface (pixel resolution, camera frame).
        margin_px: pixels added on every side.
        plane: the support plane, or None.

    Returns:
        The widened surface ((H + 2m, W + 2m), the image itself in its centre) and (H + 2m,
        W + 2m) bool its margin pixels that hold a continued surface.
    """
    k, m = surface.intrinsics, int(margin_px)
    h, w = k.shape
    wide = Intrinsics(k.fx, k.fy, k.cx + m, k.cy + m, w + 2 * m, h + 2 * m)
    vv = np.clip(np.arange(h + 2 * m) - m, 0, h - 1)[:, None]
    uu = np.clip(np.arange(w + 2 * m) - m, 0, w - 1)[None, :]
    source = surface.valid if plane is None else surface.valid & ~plane_pixels(surface, plane)
    points = surface.points_mm()[vv, uu]
    normal = surface.normal[vv, uu]
    rays = wide.ray_directions()
    with np.errstate(invalid="ignore", divide="ignore"):
        facing = -np.einsum("hwk,hwk->hw", rays, normal)
        t = np.einsum("hwk,hwk->hw", points, normal) / -facing
        ok = source[vv, uu] & (facing >= MIN_BORDER_COS) & (t > 0) \
            & (t <= 2.0 * np.linalg.norm(points, axis=-1))
        if plane is not None:
            t_plane = plane.offset_mm / (rays @ plane.normal)
            ok &= ~((t_plane > 0) & (t_plane < t))
    ok[m:m + h, m:m + w] = False
    range_mm = np.where(ok, t, np.nan)
    range_mm[m:m + h, m:m + w] = surface.range_mm
    keep = ok | np.pad(surface.valid, m)
    wide_surface = SurfaceImage(
        range_mm, np.where(keep[..., None], normal, np.nan),
        np.where(keep, surface.albedo[vv, uu], 0.0),
        np.where(keep, surface.object_id[vv, uu], -1).astype(np.int32),
        np.where(keep, surface.material_id[vv, uu], -1).astype(np.int32), wide)
    return wide_surface, ok


def world_from_surface(surface: SurfaceImage, *, leaf_mm: float = DEFAULT_LEAF_MM,
                       cutoff_deg: float = DEFAULT_CUTOFF_DEG,
                       beam_deg: float = DEFAULT_BEAM_DEG, extend_plane: bool = True,
                       others: tuple[tuple[SurfaceImage, np.ndarray], ...] = (),
                       camera_to_world: np.ndarray | None = None,
                       world_up: np.ndarray | None = None, extrude: bool = True,
                       border_fraction: float = BORDER_FRACTION) -> WorldModel:
    """The world seen in a range image (plus, optionally, other views of the same scene).

    The support plane, when one is found, replaces its pixels by an exact plane across the
    light's whole cone (its pixels' noise would otherwise make a flat table light itself);
    the other pixels are leaves as they are.

    Args:
        surface: the target view (pixel resolution); its pixels are the receivers later.
        leaf_mm: leaf size of the plane, mm (image pixels are leaves as they are).
        cutoff_deg, beam_deg: the light's cone.
        extend_plane: fit the support plane and extend it across the cone.
        others: other views as (surface, camera_to_world (4, 4) mm) in the same world frame.
        camera_to_world: (4, 4) pose of the target view (None = identity: world = camera).
        world_up: (3,) the world's up direction (the robot base's +z), or None: with it the
            support plane must be about horizontal (a large wall cannot be taken for it).
        extrude: with a support plane, extrude the off-plane surfaces down to it (walls for
            the faces no view sees, and a height field for visibility); False = the views'
            surfaces only, visibility by carving.
        border_fraction: continue the surfaces cut by the target's border past it by this
            fraction of its larger side (:func:`border_extension`); 0 = not at all.

    Returns:
        WorldModel with depth-map visibility (space carving over all views).
    """
    pose = np.eye(4) if camera_to_world is None else np.asarray(camera_to_world, np.float64)
    if pose.shape != (4, 4):
        raise InputError(f"camera_to_world: expected (4, 4), got {pose.shape}")
    notes: dict = {}
    views = [depth_view(surface, pose)]
    for other, other_pose in others:
        if other.intrinsics.shape != surface.intrinsics.shape:
            raise InputError("other views must have the target's image size")
        views.append(depth_view(other, np.asarray(other_pose, np.float64)))
    up = None if world_up is None else pose[:3, :3].T @ np.asarray(world_up, np.float64)
    plane = fit_support_plane(surface.points_mm().reshape(-1, 3), up=up) if extend_plane \
        else None
    on_plane = None if plane is None else plane_pixels(surface, plane)
    if on_plane is not None and not on_plane.any():
        plane = on_plane = None
    world_plane = None
    if plane is not None:
        n_w = pose[:3, :3] @ plane.normal
        world_plane = np.r_[n_w, plane.offset_mm + n_w @ pose[:3, 3]]
    faces, objects = _seen_surfaces(surface, pose, others, views, plane, on_plane,
                                    world_plane, border_fraction, notes)
    field = None
    if plane is not None and extrude:
        field, walls = extruded_objects(world_plane, np.concatenate([o[0] for o in objects]),
                                        np.concatenate([o[1] for o in objects]), views,
                                        cell_mm=leaf_mm / 2.0, leaf_mm=leaf_mm)
        faces += walls
        notes["extruded_wall_mm2"] = float(sum(f.area[f.valid].sum() for f in walls))
    if plane is not None:
        rho = float(np.median(surface.albedo[on_plane]))
        faces.append(_moved(_plane_face(plane, rho, leaf_mm, cutoff_deg), pose))
        notes["support_plane"] = {"normal": plane.normal.tolist(),
                                  "offset_mm": plane.offset_mm,
                                  "inlier_fraction": plane.inlier_fraction, "albedo": rho}
    tree = build_tree(faces)
    dv = DepthViews(np.stack([v[0] for v in views]), np.stack([v[1] for v in views]),
                    np.stack([v[2] for v in views]))
    light = camera_spot(pose, cutoff_deg, beam_deg)
    lit = shadow_test_views(tree.centre[:tree.n_leaves], tree.normal[:tree.n_leaves],
                            light.position, dv, field)
    return WorldModel(tree, light, pose, views=dv, lit=lit, notes=notes,
                      support_plane=world_plane, height_field=field)


def _seen_surfaces(surface: SurfaceImage, pose: np.ndarray,
                   others: tuple[tuple[SurfaceImage, np.ndarray], ...], views: list,
                   plane: Plane | None, on_plane: np.ndarray | None,
                   world_plane: np.ndarray | None, border_fraction: float, notes: dict
                   ) -> tuple[list[FaceGrid], list[tuple[np.ndarray, np.ndarray]]]:
    """The leaves of what the views show off the support plane (each surface once) and of the
    border extension, and the same surfaces as (points (M, 3) world mm, albedo (M,)) for the
    extrusion. Adds ``border_extension_px`` to ``notes`` when the border is extended."""
    keep = surface.valid if on_plane is None else surface.valid & ~on_plane
    faces = surface_faces(surface, pose, keep)
    objects = [(surface.points_mm()[keep] @ pose[:3, :3].T + pose[:3, 3],
                surface.albedo[keep])]
    for j, (other, other_pose) in enumerate(others):
        # what neither the target nor an earlier view has, and not the plane (exact below)
        other_pose = np.asarray(other_pose, np.float64)
        unseen = _unseen_pixels(other, other_pose, views[:j + 1], world_plane)
        faces += surface_faces(other, other_pose, unseen)
        objects.append((other.points_mm()[unseen] @ other_pose[:3, :3].T + other_pose[:3, 3],
                        other.albedo[unseen]))
    margin = round(border_fraction * max(surface.intrinsics.shape))
    if margin > 0:
        # assumed surfaces: leaves that send light, not a view (nothing was seen through them),
        # and not where another view saw the surface itself (no double counting)
        wide, beyond = border_extension(surface, margin, plane)
        if others:
            beyond &= _unseen_pixels(wide, pose, views, world_plane)
        faces += surface_faces(wide, pose, beyond)
        objects.append((wide.points_mm()[beyond] @ pose[:3, :3].T + pose[:3, 3],
                        wide.albedo[beyond]))
        notes["border_extension_px"] = margin
    return faces, objects


def _moved(face: FaceGrid, pose: np.ndarray) -> FaceGrid:
    rot, t = pose[:3, :3], pose[:3, 3]
    return FaceGrid(face.centre @ rot.T + t, face.normal @ rot.T, face.area, face.albedo,
                    face.valid, face.step_mm)


def _unseen_pixels(other: SurfaceImage, pose: np.ndarray, seen: list,
                   world_plane: np.ndarray | None) -> np.ndarray:
    """(H, W) bool pixels of another view that no view in ``seen`` has (no double counting)
    and that do not lie on the support plane (which is represented exactly)."""
    p = other.points_mm() @ pose[:3, :3].T + pose[:3, 3]
    keep = other.valid.copy()
    for w2c, kin, depth in seen:
        own, there = view_lookup(p, w2c, kin, depth)
        with np.errstate(invalid="ignore"):
            keep &= ~(np.abs(own - there) <= 2.0 + 0.01 * there)
    if world_plane is not None:
        n, d = world_plane[:3], world_plane[3]
        close = np.abs(p @ n - d) <= _tolerance(p - pose[:3, 3])
        facing = np.nan_to_num(other.normal @ pose[:3, :3].T @ n) >= np.cos(np.radians(25.0))
        keep &= ~(close & facing)
    return keep


def fusion_views(references: Sequence[np.ndarray | None], poses_mm: Sequence[np.ndarray | None],
                 intrinsics: Intrinsics, index: int, *, max_views: int = 4, window: int = 24,
                 min_agreement: float = 0.6, min_points: int = 200) -> list[int]:
    """Which other frames of a recording show the same scene as frame ``index``.

    A candidate agrees when most of the target's off-plane points (objects, not the shared
    table, which every scene of a cell has) that it sees land on its own reference. Among
    the agreeing frames within ``window`` of the target, those looking from the most different
    directions are chosen (they see what the target does not).

    Args:
        references: per frame (H, W) radial range in mm (NaN = missing), or None.
        poses_mm: per frame (4, 4) camera → world in mm, or None.
        intrinsics: intrinsics shared by the frames.
        index: the target frame.
        max_views: most views returned.
        window: candidates are frames index ± window.
        min_agreement: share of co-visible off-plane points that must agree.
        min_points: co-visible off-plane points needed to judge.

    Returns:
        Indices of the chosen frames (possibly empty).
    """
    ref, pose = references[index], poses_mm[index]
    if ref is None or pose is None:
        return []
    rays = intrinsics.ray_directions()
    pts = rays * np.asarray(ref, np.float64)[..., None]
    flat = pts.reshape(-1, 3)
    plane = fit_support_plane(flat)
    keep = np.all(np.isfinite(flat), axis=1)
    if plane is not None:
        keep &= np.abs(flat @ plane.normal - plane.offset_mm) > _tolerance(flat)
    target = flat[keep][::max(1, int(keep.sum()) // 3000)]
    if target.shape[0] < min_points:
        return []
    world = target @ pose[:3, :3].T + pose[:3, 3]
    scored = []
    lo, hi = max(0, index - window), min(len(references), index + window + 1)
    for j in range(lo, hi):
        if j == index or references[j] is None or poses_mm[j] is None:
            continue
        inv = np.linalg.inv(poses_mm[j])[:3]
        kin = np.array([intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy])
        own, d = view_lookup(world, inv, kin, np.asarray(references[j], np.float64))
        seen = np.isfinite(d)
        if seen.sum() < min_points:
            continue
        with np.errstate(invalid="ignore"):
            agree = np.abs(own - d) <= 2.0 + 0.01 * d
        if (agree & seen).sum() >= min_agreement * seen.sum():
            scored.append((float(pose[:3, 2] @ poses_mm[j][:3, 2]), j))
    return [j for _, j in sorted(scored)[:max_views]]


__all__ = [
    "Plane",
    "ReferenceView",
    "fit_support_plane",
    "fusion_views",
    "plane_pixels",
    "world_from_surface",
]
