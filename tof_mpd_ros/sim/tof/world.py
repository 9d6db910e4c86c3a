"""The world that light travels through: surface patches in a hierarchy, and what occludes them.

Multipath needs every surface the light source reaches, not only the pixels the camera records
(a box's side face is lit mostly by the table in front of it, often below the image). A
:class:`WorldModel` holds

* a :class:`SurfelTree`: the scene's surfaces cut into small patches (*leaves*, a few mm) that
  are merged pairwise into a binary hierarchy per face, so light from far away can be gathered
  from a few large patches and light from nearby from the small ones;
* an occluder that answers "does anything cut the segment p→q": the analytic scene
  (:func:`~tof_mpd_ros.sim.raycast.segment_blocked`) when the scene is known, or depth maps
  (space carving) when only range images are;
* the light: a spot co-located with the camera centre (position, axis, cone).

Two builders make one: :func:`world_from_scene` (the simulated cell: the table as far as the
light's cone reaches and every object face, including those the camera does not see) and
:func:`world_from_surface` (a range image alone: its pixels, the support plane extended across
the light's cone, other views fused by pose; see :mod:`.reference_world`).

Units: mm, world frame (the base frame for scenes, the camera frame for a lone image).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numba as nb
import numpy as np

from ...camera import Intrinsics
from ...errors import InputError
from ..raycast import PackedScene, pack_scene
from ..scene import PlacedObject, Scene
from ..surface import SurfaceImage
from .rays import ray_directions

#: default leaf patch size (mm): a few pixels at the cell's working distances
DEFAULT_LEAF_MM = 4.0
#: default spot cone: intensity constant up to the beam angle, falling linearly in angle to 0
#: at the cutoff (Mitsuba's ``spot`` emitter profile)
DEFAULT_CUTOFF_DEG = 60.0
DEFAULT_BEAM_DEG = 50.0
#: the table is tessellated at most this many camera heights from the camera's nadir
MAX_TABLE_REACH = 4.0


@dataclass(frozen=True)
class Spot:
    """A spot light at the camera centre.

    Attributes:
        position: (3,) float64 world position, mm.
        axis: (3,) float64 unit direction of the beam's centre (the optical axis).
        cutoff_deg: half-angle beyond which nothing is emitted, degrees.
        beam_deg: half-angle up to which the intensity is full, degrees (≤ cutoff).
    """

    position: np.ndarray
    axis: np.ndarray
    cutoff_deg: float = DEFAULT_CUTOFF_DEG
    beam_deg: float = DEFAULT_BEAM_DEG

    def __post_init__(self) -> None:
        if not 0.0 < self.beam_deg <= self.cutoff_deg <= 180.0:
            raise InputError(f"spot: need 0 < beam_deg <= cutoff_deg <= 180, got beam "
                             f"{self.beam_deg}, cutoff {self.cutoff_deg}")


def spot_profile(cos_angle: np.ndarray, cutoff_deg: float, beam_deg: float) -> np.ndarray:
    """Relative intensity of the spot at an angle to its axis (Mitsuba's ``spot`` falloff).

    Args:
        cos_angle: (...) float cosine of the angle between the axis and the direction.
        cutoff_deg, beam_deg: see :class:`Spot`.

    Returns:
        (...) float64 in [0, 1]: 1 inside the beam, linear in angle down to 0 at the cutoff.
    """
    angle = np.degrees(np.arccos(np.clip(np.asarray(cos_angle, dtype=np.float64), -1.0, 1.0)))
    if cutoff_deg <= beam_deg:
        return (angle <= cutoff_deg).astype(np.float64)
    return np.clip((cutoff_deg - angle) / (cutoff_deg - beam_deg), 0.0, 1.0)


@dataclass(frozen=True)
class SurfelTree:
    """Surface patches and their binary hierarchy (leaves are nodes ``0 .. n_leaves − 1``).

    Internal nodes come after their children, so a forward loop aggregates bottom-up.

    Attributes:
        centre: (N, 3) float64 area-weighted centre, mm.
        normal: (N, 3) float64 unit area-weighted mean normal (outward, into free space).
        area: (N,) float64 area, mm².
        albedo: (N,) float64 diffuse reflectance (area-weighted mean for internal nodes).
        radius: (N,) float64 radius of a sphere about ``centre`` holding the node, mm.
        spread: (N,) float64 bound of |n_leaf − normal| over the node's leaves.
        thickness: (N,) float64 bound of |normal · (p − centre)| over its points, mm.
        child: (N, 2) int64 children, −1 for leaves.
        roots: (R,) int64 nodes without a parent.
        n_leaves: number of leaves.
    """

    centre: np.ndarray
    normal: np.ndarray
    area: np.ndarray
    albedo: np.ndarray
    radius: np.ndarray
    spread: np.ndarray
    thickness: np.ndarray
    child: np.ndarray
    roots: np.ndarray
    n_leaves: int

    @property
    def size(self) -> int:
        """Number of nodes."""
        return int(self.area.shape[0])


@dataclass
class FaceGrid:
    """Leaves of one surface on a (nu, nv) parameter grid, before they join a tree.

    Attributes:
        centre: (nu, nv, 3) float64 leaf centres, mm.
        normal: (nu, nv, 3) float64 unit outward normals.
        area: (nu, nv) float64 leaf areas, mm².
        albedo: (nu, nv) float64 reflectance.
        valid: (nu, nv) bool leaves that exist (a disc's corners, holes of a range image).
        step_mm: (du, dv) typical leaf extent along each grid axis, mm (which axis to merge).
    """

    centre: np.ndarray
    normal: np.ndarray
    area: np.ndarray
    albedo: np.ndarray
    valid: np.ndarray
    step_mm: tuple[float, float]


def _merge_plan(valid: np.ndarray, first_id: int, step_mm: tuple[float, float],
                next_id: int) -> tuple[list[np.ndarray], int, np.ndarray]:
    """Pair grid cells until one node per connected grid remains.

    Returns:
        pairs: list of (M, 2) int64 child pairs, in creation order (ids from ``next_id``).
        next_id: the first unused id afterwards.
        roots: (R,) int64 the remaining top nodes (several when the grid has holes).
    """
    ids = np.full(valid.shape, -1, dtype=np.int64)
    ids[valid] = first_id + np.arange(int(valid.sum()))
    du, dv = step_mm
    pairs: list[np.ndarray] = []
    while ids.shape[0] > 1 or ids.shape[1] > 1:
        # merge along the axis whose cells are shorter, so nodes stay roughly square
        along_u = ids.shape[1] == 1 or (ids.shape[0] > 1 and du <= dv)
        if not along_u:
            ids = ids.T
        if ids.shape[0] % 2:
            ids = np.concatenate([ids, np.full((1, ids.shape[1]), -1, np.int64)])
        a, b = ids[0::2], ids[1::2]
        both = (a >= 0) & (b >= 0)
        merged = np.where(a >= 0, a, b)
        n_new = int(both.sum())
        merged[both] = next_id + np.arange(n_new)
        pairs.append(np.stack([a[both], b[both]], axis=1))
        next_id += n_new
        ids = merged if along_u else merged.T
        if along_u:
            du *= 2.0
        else:
            dv *= 2.0
    roots = ids.ravel()
    return pairs, next_id, roots[roots >= 0]


@nb.njit(cache=True)
def _aggregate(centre, normal, area, albedo, radius, spread, thickness, child,
               n_leaves):  # pragma: no cover - compiled
    """Fill internal nodes' fields from their children (children have lower ids)."""
    for i in range(n_leaves, area.shape[0]):
        a = child[i, 0]
        b = child[i, 1]
        wa = area[a]
        wb = area[b]
        tot = wa + wb
        area[i] = tot
        fa = wa / tot if tot > 0 else 0.5
        fb = 1.0 - fa
        albedo[i] = fa * albedo[a] + fb * albedo[b]
        nn = 0.0
        for q in range(3):
            centre[i, q] = fa * centre[a, q] + fb * centre[b, q]
            normal[i, q] = fa * normal[a, q] + fb * normal[b, q]
            nn += normal[i, q] ** 2
        nn = math.sqrt(nn)
        for q in range(3):
            normal[i, q] = normal[i, q] / nn if nn > 0 else 0.0
        rad = 0.0
        spr = 0.0
        thk = 0.0
        for c in (a, b):
            d2 = 0.0
            nd = 0.0
            dn2 = 0.0
            for q in range(3):
                d = centre[c, q] - centre[i, q]
                d2 += d * d
                nd += normal[i, q] * d
                dn2 += (normal[c, q] - normal[i, q]) ** 2
            dn = math.sqrt(dn2)
            rad = max(rad, math.sqrt(d2) + radius[c])
            spr = max(spr, dn + spread[c])
            thk = max(thk, abs(nd) + thickness[c] + dn * radius[c])
        radius[i] = rad
        spread[i] = spr
        thickness[i] = thk


def build_tree(faces: list[FaceGrid]) -> SurfelTree:
    """Join the leaves of ``faces`` into one :class:`SurfelTree` (a hierarchy per face)."""
    faces = [f for f in faces if f.valid.any()]
    if not faces:
        raise InputError("the world has no surface")
    n_leaves = sum(int(f.valid.sum()) for f in faces)
    pairs: list[np.ndarray] = []
    roots: list[np.ndarray] = []
    first, next_id = 0, n_leaves
    for f in faces:
        p, next_id, r = _merge_plan(f.valid, first, f.step_mm, next_id)
        pairs += p
        roots.append(r)
        first += int(f.valid.sum())
    n = next_id
    centre = np.zeros((n, 3))
    normal = np.zeros((n, 3))
    area = np.zeros(n)
    albedo = np.zeros(n)
    child = np.full((n, 2), -1, dtype=np.int64)
    child[n_leaves:] = np.concatenate(pairs) if pairs else np.zeros((0, 2), np.int64)
    centre[:n_leaves] = np.concatenate([f.centre[f.valid] for f in faces])
    nrm = np.concatenate([f.normal[f.valid] for f in faces])
    normal[:n_leaves] = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    area[:n_leaves] = np.concatenate([f.area[f.valid] for f in faces])
    albedo[:n_leaves] = np.concatenate([f.albedo[f.valid] for f in faces])
    radius = np.zeros(n)
    # a leaf is about square: half its diagonal bounds it
    radius[:n_leaves] = np.sqrt(area[:n_leaves] / 2.0)
    spread = np.zeros(n)
    thickness = np.zeros(n)
    _aggregate(centre, normal, area, albedo, radius, spread, thickness, child, n_leaves)
    return SurfelTree(centre, normal, area, albedo, radius, spread, thickness, child,
                      np.concatenate(roots).astype(np.int64), n_leaves)


@dataclass(frozen=True)
class DepthViews:
    """Range images that tell free space from occupied space (space carving).

    A point is occupied when it projects into at least one view and lies more than
    ``eps_mm + eps_rel·range`` behind the surface in every view it projects into (with a valid
    range there); anything else is free. One view gives the screen-space test "behind what the
    camera sees"; more views carve away space that another one saw through.

    Attributes:
        world_to_camera: (V, 3, 4) float64 world → camera optical frame, mm.
        intrinsics: (V, 4) float64 fx, fy, cx, cy (px); all views share one image size.
        range_mm: (V, H, W) float64 radial range, +inf where missing.
        eps_mm, eps_rel: occupancy tolerance.
        step_mm: spacing of the points tested along a segment, mm.
        max_steps: most points tested per segment.
        skip_mm: points this close to either end of a segment are not tested (they would see
            the end's own surface).
    """

    world_to_camera: np.ndarray
    intrinsics: np.ndarray
    range_mm: np.ndarray
    eps_mm: float = 2.0
    eps_rel: float = 0.01
    step_mm: float = 4.0
    max_steps: int = 12
    skip_mm: float = 3.0


@dataclass(frozen=True)
class HeightField:
    """Objects standing on a support plane, as columns: what is inside them is occupied.

    The plane has origin ``origin`` and unit axes ``e1``, ``e2`` in it and ``normal`` out of it
    (towards the free side); cell (i, j) covers [i, i + 1) × [j, j + 1) × ``cell_mm`` along
    (e1, e2). A point is occupied when it lies below the plane or below the cell's height.

    Attributes:
        origin, e1, e2, normal: (3,) float64 world frame, mm / unit vectors.
        cell_mm: cell size, mm.
        height_mm: (Nu, Nv) float64 column heights above the plane, mm (0 = nothing there).
    """

    origin: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    normal: np.ndarray
    cell_mm: float
    height_mm: np.ndarray

    def frame(self) -> np.ndarray:
        """(13,) float64 origin, e1, e2, normal, cell size: the compiled kernels' layout."""
        return np.concatenate([self.origin, self.e1, self.e2, self.normal,
                               [self.cell_mm]]).astype(np.float64)


@dataclass(frozen=True)
class WorldModel:
    """Everything light transport needs besides the receiving pixels.

    Attributes:
        tree: the surfaces as a patch hierarchy (world frame, mm).
        light: the spot at the camera centre.
        camera_to_world: (4, 4) float64 camera optical frame → world, mm.
        scene: the analytic scene for exact visibility (world = base frame), or None.
        views: depth maps for visibility by space carving, or None (exactly one of the two).
        lit: (n_leaves,) bool leaves the light reaches (inside the cone, unshadowed) — set by
            the builder, which knows the occluder.
        notes: what the builder assumed (for reports), e.g. the fitted support plane.
        support_plane: (4,) float64 (n, d) with n·p = d (world frame, mm) of an inferred
            support plane whose leaves are exact, or None; receiving pixels on it are snapped
            onto it so the plane does not light itself through their noise.
        height_field: objects extruded down to the support plane, used for visibility instead
            of carving the views (range-image worlds with a plane), or None.
    """

    tree: SurfelTree
    light: Spot
    camera_to_world: np.ndarray
    scene: PackedScene | None = None
    views: DepthViews | None = None
    lit: np.ndarray | None = None
    notes: dict = field(default_factory=dict)
    support_plane: np.ndarray | None = None
    height_field: HeightField | None = None

    def moved_camera(self, camera_to_world: np.ndarray) -> WorldModel:
        """The same world with the receiving camera at another pose (a pose error's true
        camera); the light and what it lights stay (a shift of a few mm changes little)."""
        return replace(self, camera_to_world=np.asarray(camera_to_world, np.float64))


# --- the simulated cell's scene -----------------------------------------------------------


def _grid(nu: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """Cell-centre parameters (nu, nv) in (0, 1)²."""
    u = (np.arange(nu) + 0.5) / nu
    v = (np.arange(nv) + 0.5) / nv
    return np.meshgrid(u, v, indexing="ij")


def _cells(length_mm: float, leaf_mm: float) -> int:
    return max(1, math.ceil(length_mm / leaf_mm))


def _rect_face(origin: np.ndarray, eu: np.ndarray, ev: np.ndarray, albedo: float,
               leaf_mm: float, inside=None, true_area: float | None = None) -> FaceGrid:
    """A planar parallelogram origin + u·eu + v·ev (u, v in [0, 1]) with normal eu × ev.

    ``inside(u, v)`` keeps the cells whose centre lies in a sub-shape (a triangle, a disc);
    their areas are then rescaled so the kept cells add up to ``true_area``.
    """
    lu, lv = float(np.linalg.norm(eu)), float(np.linalg.norm(ev))
    nu, nv = _cells(lu, leaf_mm), _cells(lv, leaf_mm)
    u, v = _grid(nu, nv)
    centre = origin + u[..., None] * eu + v[..., None] * ev
    n = np.cross(eu, ev)
    n = n / np.linalg.norm(n)
    valid = np.ones((nu, nv), bool) if inside is None else inside(u, v)
    area = np.full((nu, nv), lu * lv / (nu * nv))
    if true_area is not None and valid.any():
        area *= true_area / area[valid].sum()
    return FaceGrid(centre, np.broadcast_to(n, centre.shape).copy(), area,
                    np.full((nu, nv), albedo), valid, (lu / nu, lv / nv))


def _in_triangle(apex_u: float, swap: bool = False):
    """Cell-centre test for the triangle (0,0) (1,0) (apex_u,1) of a parallelogram grid
    (``swap``: the grid's axes are exchanged)."""
    def inside(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        if swap:
            u, v = v, u
        return (u >= apex_u * v) & (u <= 1.0 - (1.0 - apex_u) * v)
    return inside


def _in_disc(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Cell-centre test for the disc inscribed in the unit square."""
    return (u - 0.5) ** 2 + (v - 0.5) ** 2 <= 0.25


def _to_base(obj: PlacedObject, p: np.ndarray) -> np.ndarray:
    pose = obj.object_to_base_mm
    return p @ pose[:3, :3].T + pose[:3, 3]


def _box_faces(obj: PlacedObject, leaf_mm: float) -> list[FaceGrid]:
    """The five faces of a box that can be lit (its bottom rests on the table)."""
    sx, sy, sz = obj.spec.dims_mm
    rot = obj.object_to_base_mm[:3, :3]
    o = _to_base(obj, np.array([-sx / 2, -sy / 2, 0.0]))
    ex, ey, ez = rot[:, 0] * sx, rot[:, 1] * sy, rot[:, 2] * sz
    rho = obj.spec.albedo
    return [_rect_face(o + ez, ex, ey, rho, leaf_mm),           # top, +z
            _rect_face(o, ex, ez, rho, leaf_mm),                # −y
            _rect_face(o + ey, ez, ex, rho, leaf_mm),           # +y
            _rect_face(o, ez, ey, rho, leaf_mm),                # −x
            _rect_face(o + ex, ey, ez, rho, leaf_mm)]           # +x


def _prism_faces(obj: PlacedObject, leaf_mm: float) -> list[FaceGrid]:
    """The two triangular ends and two slanted faces of a prism (not its bottom)."""
    sx, sy, sz = obj.spec.dims_mm
    rot = obj.object_to_base_mm[:3, :3]
    a = obj.spec.apex_offset_mm
    left = _to_base(obj, np.array([-sx / 2, -sy / 2, 0.0]))
    right = _to_base(obj, np.array([sx / 2, -sy / 2, 0.0]))
    apex = _to_base(obj, np.array([a, -sy / 2, sz]))
    ey = rot[:, 1] * sy
    rho = obj.spec.albedo
    apex_u = (a + sx / 2) / sx
    base = right - left
    up = apex - left - apex_u * base          # vertical, length sz
    tri = 0.5 * sx * sz
    return [_rect_face(left, base, up, rho, leaf_mm, _in_triangle(apex_u), tri),        # −y
            _rect_face(left + ey, up, base, rho, leaf_mm, _in_triangle(apex_u, True), tri),
            _rect_face(left, apex - left, ey, rho, leaf_mm),                            # −x side
            _rect_face(right, ey, apex - right, rho, leaf_mm)]                          # +x side


def _cylinder_faces(obj: PlacedObject, leaf_mm: float) -> list[FaceGrid]:
    r = obj.spec.dims_mm[0] / 2.0
    h = obj.spec.dims_mm[2]
    rho = obj.spec.albedo
    n_t = max(8, _cells(2 * math.pi * r, leaf_mm))
    n_z = _cells(h, leaf_mm)
    u, v = _grid(n_t, n_z)
    ang = 2 * math.pi * u
    local_n = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=-1)
    local_p = np.stack([r * np.cos(ang), r * np.sin(ang), h * v], axis=-1)
    rot = obj.object_to_base_mm[:3, :3]
    side = FaceGrid(_to_base(obj, local_p), local_n @ rot.T,
                    np.full((n_t, n_z), 2 * math.pi * r * h / (n_t * n_z)),
                    np.full((n_t, n_z), rho), np.ones((n_t, n_z), bool),
                    (2 * math.pi * r / n_t, h / n_z))
    o = _to_base(obj, np.array([-r, -r, h]))
    top = _rect_face(o, rot[:, 0] * 2 * r, rot[:, 1] * 2 * r, rho, leaf_mm, _in_disc,
                     math.pi * r * r)
    return [side, top]


def _sphere_faces(obj: PlacedObject, leaf_mm: float) -> list[FaceGrid]:
    r = obj.spec.dims_mm[0] / 2.0
    rho = obj.spec.albedo
    n_p = max(8, _cells(2 * math.pi * r, leaf_mm))
    n_c = max(4, _cells(math.pi * r, leaf_mm))
    u, v = _grid(n_p, n_c)
    phi = 2 * math.pi * u
    cz = 1.0 - 2.0 * v  # equal-area bands in cos(polar angle)
    sz = np.sqrt(1.0 - cz ** 2)
    local_n = np.stack([sz * np.cos(phi), sz * np.sin(phi), cz], axis=-1)
    local_p = r * local_n + np.array([0.0, 0.0, r])
    rot = obj.object_to_base_mm[:3, :3]
    return [FaceGrid(_to_base(obj, local_p), local_n @ rot.T,
                     np.full((n_p, n_c), 4 * math.pi * r * r / (n_p * n_c)),
                     np.full((n_p, n_c), rho), np.ones((n_p, n_c), bool),
                     (2 * math.pi * r / n_p, math.pi * r / n_c))]


_OBJECT_FACES = {"box": _box_faces, "prism": _prism_faces, "cylinder": _cylinder_faces,
                 "sphere": _sphere_faces}


def cone_footprint_xy(light: Spot, plane_z: float, reach_mm: float) -> np.ndarray:
    """(K, 2) float64 points bounding where the spot's cone meets the plane z = ``plane_z``.

    Directions that never meet the plane (above the horizon) are cut at ``reach_mm`` from the
    light's nadir, as is everything farther.
    """
    a = light.axis / np.linalg.norm(light.axis)
    e1 = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    c = math.cos(math.radians(min(light.cutoff_deg, 89.0)))
    s = math.sin(math.radians(min(light.cutoff_deg, 89.0)))
    phi = np.linspace(0.0, 2 * math.pi, 72, endpoint=False)
    dirs = c * a + s * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    dirs = np.concatenate([dirs, a[None]])
    p0 = light.position
    height = p0[2] - plane_z
    out = []
    for d in dirs:
        horiz = np.hypot(d[0], d[1])
        if d[2] < 0 and height > 0:
            t = height / -d[2]
            xy = p0[:2] + t * d[:2]
        else:
            xy = p0[:2] + (reach_mm * d[:2] / horiz if horiz > 0 else 0.0)
        off = xy - p0[:2]
        dist = np.hypot(*off)
        if dist > reach_mm:
            xy = p0[:2] + off * reach_mm / dist
        out.append(xy)
    return np.asarray(out)


def _table_face(scene: Scene, light: Spot, leaf_mm: float) -> FaceGrid:
    t = scene.table
    height = light.position[2] - t.height_mm
    if height <= 0:
        raise InputError("the light is not above the table")
    pts = cone_footprint_xy(light, t.height_mm, MAX_TABLE_REACH * height)
    lo = np.maximum(pts.min(axis=0), np.subtract(t.centre_xy_mm, t.half_extent_mm))
    hi = np.minimum(pts.max(axis=0), np.add(t.centre_xy_mm, t.half_extent_mm))
    hi = np.maximum(hi, lo + leaf_mm)
    origin = np.array([lo[0], lo[1], t.height_mm])
    ex = np.array([hi[0] - lo[0], 0.0, 0.0])
    ey = np.array([0.0, hi[1] - lo[1], 0.0])
    face = _rect_face(origin, ex, ey, t.albedo, leaf_mm)
    # table under a flat-bottomed object is covered: no light reaches it, none leaves it
    xy = face.centre[..., :2]
    for obj in scene.objects:
        if obj.spec.kind == "sphere":
            continue
        poly = obj.footprint_base()
        inside = np.ones(xy.shape[:2], bool)
        for k in range(len(poly)):
            p, q = poly[k], poly[(k + 1) % len(poly)]
            inside &= (q[0] - p[0]) * (xy[..., 1] - p[1]) - (q[1] - p[1]) * (xy[..., 0] - p[0]) \
                > 0
        face.valid &= ~inside
    return face


def camera_spot(camera_to_world: np.ndarray, cutoff_deg: float = DEFAULT_CUTOFF_DEG,
                beam_deg: float = DEFAULT_BEAM_DEG) -> Spot:
    """The spot co-located with a camera: at its centre, along its optical axis (+z)."""
    pose = np.asarray(camera_to_world, dtype=np.float64)
    return Spot(pose[:3, 3].copy(), pose[:3, 2] / np.linalg.norm(pose[:3, 2]), cutoff_deg,
                beam_deg)


def world_from_scene(scene: Scene, camera_to_base_mm: np.ndarray, *,
                     leaf_mm: float = DEFAULT_LEAF_MM, cutoff_deg: float = DEFAULT_CUTOFF_DEG,
                     beam_deg: float = DEFAULT_BEAM_DEG) -> WorldModel:
    """The world of a simulated scene seen from a camera pose (world = base frame).

    Args:
        scene: table and objects (base frame, mm).
        camera_to_base_mm: (4, 4) camera optical frame → base, mm; the light sits at its centre.
        leaf_mm: leaf patch size, mm.
        cutoff_deg, beam_deg: the light's cone (see :class:`Spot`).

    Returns:
        WorldModel with exact (analytic) visibility; ``lit`` from shadow rays to the light.
    """
    pose = np.asarray(camera_to_base_mm, dtype=np.float64)
    light = camera_spot(pose, cutoff_deg, beam_deg)
    faces = [_table_face(scene, light, leaf_mm)]
    for obj in scene.objects:
        faces += _OBJECT_FACES[obj.spec.kind](obj, leaf_mm)
    tree = build_tree(faces)
    packed = pack_scene(scene)
    lit = _lit_by_scene(tree, light, packed)
    return WorldModel(tree, light, pose, scene=packed, lit=lit)


def _lit_by_scene(tree: SurfelTree, light: Spot, packed: PackedScene) -> np.ndarray:
    from .transport import shadow_test_scene  # the transport owns the compiled kernels
    return shadow_test_scene(tree.centre[:tree.n_leaves], tree.normal[:tree.n_leaves],
                             light.position, packed)


# --- a range image --------------------------------------------------------------------------


#: directions pixels are grouped by before their patches are merged (the 26 of a 3×3×3 grid)
_NORMAL_BINS = np.array([d for d in np.ndindex(3, 3, 3) if d != (1, 1, 1)], float) - 1.0
_NORMAL_BINS /= np.linalg.norm(_NORMAL_BINS, axis=1, keepdims=True)


def surface_faces(surface: SurfaceImage, camera_to_world: np.ndarray,
                  keep: np.ndarray | None = None) -> list[FaceGrid]:
    """The pixels of a (pixel-resolution) surface image as leaves, moved to the world frame.

    Pixels are grouped into faces — connected regions whose normals fall in one of 26
    direction bins — so the hierarchy merges patches of one surface, not across a crease or a
    depth edge (such nodes could never be gathered whole).

    Args:
        surface: what the camera sees.
        camera_to_world: (4, 4) camera → world, mm.
        keep: (H, W) bool pixels to use (None = every pixel with a surface).
    """
    from scipy.ndimage import find_objects, label

    from .transport import pixel_area_mm2
    rays = ray_directions(surface.intrinsics)
    points = rays * surface.range_mm[..., None]
    ok = surface.valid & np.all(np.isfinite(surface.normal), axis=-1)
    if keep is not None:
        ok &= keep
    area = np.nan_to_num(pixel_area_mm2(surface))
    ok &= area > 0
    rot, t = camera_to_world[:3, :3], camera_to_world[:3, 3]
    centre = np.nan_to_num(points) @ rot.T + t
    normal = np.nan_to_num(surface.normal) @ rot.T
    # the grid axes are the image's (pixel pitch at 300 mm)
    pitch = 300.0 / surface.intrinsics.fx
    bins = np.argmax(np.nan_to_num(surface.normal) @ _NORMAL_BINS.T, axis=-1)
    faces = []
    for b in np.unique(bins[ok]):
        regions, _ = label(ok & (bins == b))
        for index, box in enumerate(find_objects(regions), start=1):
            if box is None:
                continue
            mask = regions[box] == index
            faces.append(FaceGrid(centre[box], normal[box], area[box], surface.albedo[box],
                                  mask, (pitch, pitch)))
    return faces


def depth_view(surface: SurfaceImage, camera_to_world: np.ndarray) -> tuple[np.ndarray,
                                                                          np.ndarray,
                                                                          np.ndarray]:
    """(3, 4) world → camera, (4,) fx fy cx cy and (H, W) range (+inf = missing) of a view."""
    inv = np.linalg.inv(camera_to_world)
    k: Intrinsics = surface.intrinsics
    depth = np.where(surface.valid, surface.range_mm, np.inf)
    return inv[:3], np.array([k.fx, k.fy, k.cx, k.cy]), depth


__all__ = ["DepthViews", "FaceGrid", "HeightField", "Spot", "SurfelTree", "WorldModel",
           "build_tree", "camera_spot", "cone_footprint_xy", "depth_view", "spot_profile",
           "surface_faces",
           "world_from_scene"]
