"""Analytic ray casting of a :class:`~tof_mpd_ros.sim.scene.Scene`: the package's one ray caster.

:func:`cast_rays` packs the scene into flat arrays (:func:`pack_scene`, columns named by the
``TABLE_*``, ``GEOM_*`` and ``PLANE_*`` indices below) and runs one compiled (numba) kernel over
the rays in parallel; per ray it tests the table and then each object, culled by its bounding
sphere. :func:`sl_ranges` (the structured-light scan) and :func:`segment_blocked` (the
simulator's light transport) use the same per-ray kernels. A plain-numpy version that evaluates
the same floating-point expressions in the same order, all rays at once, is the test oracle
(``test/oracles/raycast_reference.py``, not shipped): both give bit-identical hits.

Units: origins, hit distances and the scene in **millimetres**, base frame; directions are unit
vectors. Camera poses passed to :func:`render_surface` are camera-to-base with the translation in
**millimetres** (convert a ROS pose in metres with :func:`~tof_mpd_ros.pose.pose_m_to_mm`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numba as nb
import numpy as np

from ..camera import Intrinsics
from ..errors import InputError
from ..pose import rotate
from ..validation import check_array
from .scene import Scene
from .surface import SurfaceImage

# Hits closer than this to the ray origin are ignored, so a ray leaving a surface does not
# hit that same surface again (mm).
T_MIN_MM = 1e-6


@dataclass
class RayHits:
    """Nearest surface along each of N rays.

    Attributes:
        t_mm: (N,) float64 distance from the origin along the unit direction, mm; inf = miss.
        normal: (N, 3) float64 outward unit normals in the base frame; NaN on a miss.
        object_id: (N,) int32: 0 = table, k > 0 = ``scene_index`` k, -1 = miss.
        albedo: (N,) float64 reflectance in [0, 1]; 0 on a miss (nothing reflects).
        material_id: (N,) int32 material index; -1 on a miss.
    """

    t_mm: np.ndarray
    normal: np.ndarray
    object_id: np.ndarray
    albedo: np.ndarray
    material_id: np.ndarray


# Columns of PackedScene.table: the table top's height, centre x, y, half extents x, y (mm) and
# albedo. The kernels read these names (numba freezes module-level ints as constants).
TABLE_Z, TABLE_CX, TABLE_CY, TABLE_HALF_X, TABLE_HALF_Y, TABLE_ALBEDO = range(6)
N_TABLE = 6
# Columns of PackedScene.geom, one row per object: its position (mm), cos and sin of its yaw,
# its bounding sphere's centre (mm), radius squared and radius (the cull), and the shape radius
# (cylinder, sphere) and its square.
(GEOM_X, GEOM_Y, GEOM_Z, GEOM_COS_YAW, GEOM_SIN_YAW, GEOM_BOUND_X, GEOM_BOUND_Y, GEOM_BOUND_Z,
 GEOM_BOUND_R2, GEOM_SHAPE_R, GEOM_SHAPE_R2, GEOM_BOUND_R) = range(12)
N_GEOM = 12
# Columns of PackedScene.planes[k, i]: outward unit normal x, y, z and offset (mm) of plane i.
PLANE_NX, PLANE_NY, PLANE_NZ, PLANE_OFFSET = range(4)
# PackedScene.kind codes.
KIND_POLYHEDRON, KIND_CYLINDER, KIND_SPHERE = 0, 1, 2
_KIND_CODES = {"box": KIND_POLYHEDRON, "prism": KIND_POLYHEDRON, "cylinder": KIND_CYLINDER,
               "sphere": KIND_SPHERE}
# planes per polyhedron (a box has 6, a prism 5)
_MAX_PLANES = 6


@dataclass(frozen=True)
class PackedScene:
    """The scene as flat arrays for the kernel (object k of the arrays = ``scene.objects[k]``).

    Attributes:
        table: (N_TABLE,) float64 indexed by ``TABLE_*``: height, centre x, centre y, half
            extent x, half extent y (mm), albedo.
        kind: (K,) int64 ``KIND_POLYHEDRON``, ``KIND_CYLINDER`` or ``KIND_SPHERE``.
        geom: (K, N_GEOM) float64 indexed by ``GEOM_*``: x, y, z (mm), cos yaw, sin yaw,
            bounding-sphere centre x, y, z (mm), its radius squared (mm^2), shape radius
            (cylinder, sphere; mm), shape radius squared (mm^2), bounding-sphere radius (mm).
        height: (K,) float64 cylinder height, mm.
        planes: (K, 6, 4) float64 polyhedron planes indexed by ``PLANE_*`` (unit normal, offset
            in mm); ``n_planes`` (K,) int64 of them are used.
    """

    table: np.ndarray
    kind: np.ndarray
    geom: np.ndarray
    height: np.ndarray
    planes: np.ndarray
    n_planes: np.ndarray


def pack_scene(scene: Scene) -> PackedScene:
    """Flatten ``scene`` for the kernels (the same scalars the numpy oracle uses), mm."""
    t = scene.table
    table = np.zeros(N_TABLE)
    table[[TABLE_Z, TABLE_CX, TABLE_CY, TABLE_HALF_X, TABLE_HALF_Y, TABLE_ALBEDO]] = [
        t.height_mm, t.centre_xy_mm[0], t.centre_xy_mm[1], t.half_extent_mm[0],
        t.half_extent_mm[1], t.albedo]
    k = len(scene.objects)
    kind = np.zeros(k, dtype=np.int64)
    geom = np.zeros((k, N_GEOM))
    height = np.zeros(k)
    planes = np.zeros((k, _MAX_PLANES, 4))
    n_planes = np.zeros(k, dtype=np.int64)
    for i, obj in enumerate(scene.objects):
        spec = obj.spec
        kind[i] = _KIND_CODES[spec.kind]
        centre, radius = obj.bounding_sphere()
        shape_r = spec.dims_mm[0] / 2.0
        g = geom[i]
        g[GEOM_X], g[GEOM_Y], g[GEOM_Z] = obj.x_mm, obj.y_mm, obj.z_mm
        g[GEOM_COS_YAW], g[GEOM_SIN_YAW] = np.cos(obj.yaw_rad), np.sin(obj.yaw_rad)
        g[GEOM_BOUND_X], g[GEOM_BOUND_Y], g[GEOM_BOUND_Z] = centre
        g[GEOM_BOUND_R2], g[GEOM_BOUND_R] = radius**2, radius
        g[GEOM_SHAPE_R], g[GEOM_SHAPE_R2] = shape_r, shape_r**2
        height[i] = spec.dims_mm[2]
        if kind[i] == KIND_POLYHEDRON:
            normals, offsets = spec.polyhedron_planes()
            n_planes[i] = len(offsets)
            planes[i, :len(offsets), PLANE_NX:PLANE_NZ + 1] = normals
            planes[i, :len(offsets), PLANE_OFFSET] = offsets
    return PackedScene(table, kind, geom, height, planes, n_planes)


@nb.njit(cache=True, inline="always")
def _dot3(n0, n1, n2, x, y, z):  # pragma: no cover - compiled
    """n . (x, y, z) skipping zero coefficients, summed left to right (as ``_dot``)."""
    acc = 0.0
    first = True
    if n0 != 0.0:
        acc = n0 * x
        first = False
    if n1 != 0.0:
        acc = n1 * y if first else acc + n1 * y
        first = False
    if n2 != 0.0:
        acc = n2 * z if first else acc + n2 * z
    return acc


@nb.njit(cache=True, inline="always")
def _kernel_polyhedron(planes, n_planes, ox, oy, oz, dx, dy, dz):  # pragma: no cover
    """Entry t (inf = miss) and the entry plane index, object frame (as ``_hit_polyhedron``)."""
    t_in = -np.inf
    t_out = np.inf
    k_in = 0
    open_ = True
    for k in range(n_planes):
        a = planes[k, PLANE_NX]
        b = planes[k, PLANE_NY]
        c = planes[k, PLANE_NZ]
        denom = _dot3(a, b, c, dx, dy, dz)
        inside_by = planes[k, PLANE_OFFSET] - _dot3(a, b, c, ox, oy, oz)
        if denom < 0.0:
            t = inside_by / denom
            if t > t_in:
                t_in = t
                k_in = k
        elif denom > 0.0:
            t = inside_by / denom
            if t < t_out:
                t_out = t
        elif inside_by < 0.0:
            open_ = False
    if open_ and t_in <= t_out and t_in > T_MIN_MM:
        return t_in, k_in
    return np.inf, k_in


@nb.njit(cache=True, inline="always")
def _kernel_slab_z(oz, dz, top):  # pragma: no cover - compiled
    """(lo, hi) of t inside 0 <= z <= top (as ``_slab_z``)."""
    if dz == 0.0:
        if oz >= 0.0 and oz <= top:
            return -np.inf, np.inf
        return np.inf, -np.inf
    t0 = -oz / dz
    t1 = (top - oz) / dz
    return min(t0, t1), max(t0, t1)


@nb.njit(cache=True, inline="always")
def _kernel_cylinder(radius, radius2, height, ox, oy, oz, dx, dy, dz):  # pragma: no cover
    """Entry t (inf = miss) and normal, object frame (as ``_hit_cylinder``)."""
    a = dx * dx + dy * dy
    b = ox * dx + oy * dy
    c = ox * ox + oy * oy - radius2
    disc = b * b - a * c
    root = math.sqrt(max(disc, 0.0))
    if a < 1e-12:
        side_lo = -np.inf if c <= 0.0 else np.inf
        side_hi = np.inf if c <= 0.0 else -np.inf
    else:
        side_lo = (-b - root) / a
        side_hi = (-b + root) / a
    if disc < 0.0:
        side_lo = np.inf
    cap_lo, cap_hi = _kernel_slab_z(oz, dz, height)
    t_in = max(side_lo, cap_lo)
    if not (t_in <= min(side_hi, cap_hi) and t_in > T_MIN_MM):
        return np.inf, 0.0, 0.0, 0.0
    if side_lo >= cap_lo:
        return t_in, (ox + t_in * dx) / radius, (oy + t_in * dy) / radius, 0.0
    return t_in, 0.0, 0.0, -1.0 if dz > 0.0 else (1.0 if dz < 0.0 else 0.0)


@nb.njit(cache=True, inline="always")
def _kernel_sphere(radius, radius2, ox, oy, oz, dx, dy, dz):  # pragma: no cover - compiled
    """Entry t (inf = miss) and normal, object frame (as ``_hit_sphere``)."""
    ocz = oz - radius
    b = ox * dx + oy * dy + ocz * dz
    c = ox * ox + oy * oy + ocz * ocz - radius2
    disc = b * b - c
    t_in = -b - math.sqrt(max(disc, 0.0))
    if not (disc >= 0.0 and t_in > T_MIN_MM):
        return np.inf, 0.0, 0.0, 0.0
    return t_in, (ox + t_in * dx) / radius, (oy + t_in * dy) / radius, (ocz + t_in * dz) / radius


@nb.njit(cache=True, inline="always")
def _object_hit(k, kind, g, height, planes, n_planes, ox, oy, oz, dx, dy,
                dz):  # pragma: no cover - compiled
    """Entry t of object k along a base-frame ray (inf = miss) and its object-frame normal:
    the ray is moved into the object's frame (yaw only) and the object's kernel runs."""
    c = g[GEOM_COS_YAW]
    s = g[GEOM_SIN_YAW]
    x = ox - g[GEOM_X]
    y = oy - g[GEOM_Y]
    lox = c * x + s * y
    loy = c * y - s * x
    loz = oz - g[GEOM_Z]
    ldx = c * dx + s * dy
    ldy = c * dy - s * dx
    if kind[k] == KIND_POLYHEDRON:
        tk, kp = _kernel_polyhedron(planes[k], n_planes[k], lox, loy, loz, ldx, ldy, dz)
        return tk, planes[k, kp, PLANE_NX], planes[k, kp, PLANE_NY], planes[k, kp, PLANE_NZ]
    if kind[k] == KIND_CYLINDER:
        return _kernel_cylinder(g[GEOM_SHAPE_R], g[GEOM_SHAPE_R2], height[k], lox, loy, loz, ldx,
                                ldy, dz)
    return _kernel_sphere(g[GEOM_SHAPE_R], g[GEOM_SHAPE_R2], lox, loy, loz, ldx, ldy, dz)


@nb.njit(cache=True, inline="always")
def _nearest_hit(ox, oy, oz, dx, dy, dz, table, kind, geom, height, planes,
                 n_planes):  # pragma: no cover - compiled
    """Nearest hit of one ray: (t (inf = miss), base-frame normal (NaN on a miss), hit index
    (-1 miss, 0 table, k + 1 object k)), the table first, then the objects in order."""
    best = np.inf
    nx_b = np.nan
    ny_b = np.nan
    nz_b = np.nan
    which = -1
    # table (from either side)
    t = (table[TABLE_Z] - oz) / dz
    if ((t - t) == 0.0 and t > T_MIN_MM
            and abs(ox + t * dx - table[TABLE_CX]) <= table[TABLE_HALF_X]
            and abs(oy + t * dy - table[TABLE_CY]) <= table[TABLE_HALF_Y]):
        best = t
        nx_b = 0.0
        ny_b = 0.0
        nz_b = 1.0
        which = 0
    for k in range(kind.shape[0]):
        g = geom[k]
        # bounding-sphere cull in the base frame
        cx = g[GEOM_BOUND_X] - ox
        cy = g[GEOM_BOUND_Y] - oy
        cz = g[GEOM_BOUND_Z] - oz
        along = cx * dx + cy * dy + cz * dz
        dist2 = cx * cx + cy * cy + cz * cz - along * along
        if not (dist2 <= g[GEOM_BOUND_R2] and along + g[GEOM_BOUND_R] > 0.0):
            continue
        c = g[GEOM_COS_YAW]
        s = g[GEOM_SIN_YAW]
        tk, nx, ny, nz = _object_hit(k, kind, g, height, planes, n_planes, ox, oy, oz, dx, dy,
                                     dz)
        if tk < best:
            best = tk
            nx_b = c * nx - s * ny
            ny_b = s * nx + c * ny
            nz_b = nz
            which = k + 1
    return best, nx_b, ny_b, nz_b, which


@nb.njit(cache=True, inline="always")
def segment_blocked(ox, oy, oz, qx, qy, qz, t_lo, t_hi_margin, table, kind, geom, height,
                    planes, n_planes):  # pragma: no cover - compiled
    """Whether any scene surface cuts the segment from o to q (base frame, mm).

    A hit counts when it lies farther than ``t_lo`` from o and nearer than ``|q − o| −
    t_hi_margin``: the margins keep the segment's own end surfaces (and, for an aggregated
    patch, the chord of a curved one) from blocking it. The same intersection kernels as
    :func:`_nearest_hit`, stopping at the first blocking hit. ``table``, ``kind``, ``geom``,
    ``height``, ``planes``, ``n_planes`` are the fields of :class:`PackedScene`.
    """
    dx = qx - ox
    dy = qy - oy
    dz = qz - oz
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    if not length > 0.0:
        return False
    dx /= length
    dy /= length
    dz /= length
    t_hi = length - t_hi_margin
    if t_hi <= t_lo:
        return False
    t = (table[TABLE_Z] - oz) / dz
    if ((t - t) == 0.0 and t > t_lo and t < t_hi
            and abs(ox + t * dx - table[TABLE_CX]) <= table[TABLE_HALF_X]
            and abs(oy + t * dy - table[TABLE_CY]) <= table[TABLE_HALF_Y]):
        return True
    for k in range(kind.shape[0]):
        g = geom[k]
        cx = g[GEOM_BOUND_X] - ox
        cy = g[GEOM_BOUND_Y] - oy
        cz = g[GEOM_BOUND_Z] - oz
        along = cx * dx + cy * dy + cz * dz
        dist2 = cx * cx + cy * cy + cz * cz - along * along
        if not (dist2 <= g[GEOM_BOUND_R2] and along + g[GEOM_BOUND_R] > t_lo
                and along - g[GEOM_BOUND_R] < t_hi):
            continue
        tk = _object_hit(k, kind, g, height, planes, n_planes, ox, oy, oz, dx, dy, dz)[0]
        if tk > t_lo and tk < t_hi:
            return True
    return False


@nb.njit(parallel=True, cache=True)
def _cast_kernel(ox_a, oy_a, oz_a, stride, dx_a, dy_a, dz_a, table, kind, geom, height, planes,
                 n_planes):  # pragma: no cover - compiled
    """Nearest hit per ray: t (inf = miss), base-frame normal, hit index (-1 miss, 0 table,
    k + 1 object k). Origins are (1,) arrays with ``stride`` 0 (shared), else (N,) with 1."""
    n = dx_a.shape[0]
    t_out = np.empty(n)
    nrm = np.empty((n, 3))
    which = np.empty(n, dtype=np.int64)
    for i in nb.prange(n):
        j = i * stride
        t_out[i], nrm[i, 0], nrm[i, 1], nrm[i, 2], which[i] = _nearest_hit(
            ox_a[j], oy_a[j], oz_a[j], dx_a[i], dy_a[i], dz_a[i], table, kind, geom, height,
            planes, n_planes)
    return t_out, nrm, which


@nb.njit(parallel=True, cache=True)
def _sl_kernel(dirs, origin, projector, proj_rot, proj_k, cos_min, tol_mm, table, kind, geom,
               height, planes, n_planes):  # pragma: no cover - compiled
    """Range of each SL camera ray that the camera sees and the projector lights, else NaN.

    Args:
        dirs: (N, 3) base-frame unit ray directions; origin: (3,) the SL camera centre.
        projector: (3,) projector centre (base frame); proj_rot: (3, 3) base -> projector
            rotation; proj_k: (fx, fy, cx, cy, width, height) of its pattern grid.
        cos_min: smallest cosine of incidence measured; tol_mm: visibility tolerance.
    """
    n = dirs.shape[0]
    out = np.full(n, np.nan)
    for i in nb.prange(n):
        dx = dirs[i, 0]
        dy = dirs[i, 1]
        dz = dirs[i, 2]
        t, nx, ny, nz, which = _nearest_hit(origin[0], origin[1], origin[2], dx, dy, dz, table,
                                            kind, geom, height, planes, n_planes)
        if which < 0:
            continue
        # surfaces are seen from either side: |cos| of the incidence
        if abs(nx * dx + ny * dy + nz * dz) < cos_min:
            continue
        px = origin[0] + t * dx
        py = origin[1] + t * dy
        pz = origin[2] + t * dz
        # inside the projector's field of view
        ox = px - projector[0]
        oy = py - projector[1]
        oz = pz - projector[2]
        lz = proj_rot[2, 0] * ox + proj_rot[2, 1] * oy + proj_rot[2, 2] * oz
        if not lz > 0.0:
            continue
        lx = proj_rot[0, 0] * ox + proj_rot[0, 1] * oy + proj_rot[0, 2] * oz
        ly = proj_rot[1, 0] * ox + proj_rot[1, 1] * oy + proj_rot[1, 2] * oz
        u = proj_k[0] * lx / lz + proj_k[2]
        v = proj_k[1] * ly / lz + proj_k[3]
        if not (u >= -0.5 and u <= proj_k[4] - 0.5 and v >= -0.5 and v <= proj_k[5] - 0.5):
            continue
        # not occluded from the projector
        dist = math.sqrt(ox * ox + oy * oy + oz * oz)
        if not dist > 0.0:
            continue
        ts = _nearest_hit(projector[0], projector[1], projector[2], ox / dist, oy / dist,
                          oz / dist, table, kind, geom, height, planes, n_planes)[0]
        if ts >= dist - tol_mm:
            out[i] = t
    return out


def sl_ranges(scene: Scene, sl_to_base_mm: np.ndarray, intrinsics: Intrinsics,
              projector_to_base_mm: np.ndarray, *, max_incidence_deg: float,
              tol_mm: float) -> np.ndarray:
    """Range of every structured-light pixel that the camera sees and the projector lights.

    One compiled pass per pixel: the camera ray's nearest hit; the cosine of incidence at
    least ``cos(max_incidence_deg)``; the point inside the projector's field of view (the
    projector looks along its own z with ``intrinsics``); no surface between the projector and
    the point nearer than its distance minus ``tol_mm``. The camera rays are the same as
    :func:`render_surface`'s, so measured ranges are bit-identical to its ranges.

    Args:
        scene: the scene (base frame, mm).
        sl_to_base_mm: (4, 4) SL camera optical frame -> base frame, mm.
        intrinsics: the SL camera's image grid, also the projector's pattern grid.
        projector_to_base_mm: (4, 4) projector frame -> base frame, mm.
        max_incidence_deg: surfaces seen more obliquely are not measured, degrees.
        tol_mm: projector visibility tolerance, mm.

    Returns:
        (H*W,) float64 radial range along each camera ray, mm; NaN = not measured.
    """
    pose = check_array("sl_to_base_mm", sl_to_base_mm, ndim=2, shape=(4, 4),
                       dtype_kind="fiu").astype(np.float64, copy=False)
    proj = np.asarray(projector_to_base_mm, dtype=np.float64)
    dirs = np.ascontiguousarray(rotate(camera_rays(intrinsics), pose[:3, :3]))
    k = intrinsics
    p = pack_scene(scene)
    return _sl_kernel(dirs, np.ascontiguousarray(pose[:3, 3]), np.ascontiguousarray(proj[:3, 3]),
                      np.ascontiguousarray(proj[:3, :3].T),
                      np.array([k.fx, k.fy, k.cx, k.cy, k.width, k.height], dtype=np.float64),
                      math.cos(math.radians(max_incidence_deg)), float(tol_mm), p.table, p.kind,
                      p.geom, p.height, p.planes, p.n_planes)


def cast_rays(scene: Scene, origins_mm: np.ndarray, directions: np.ndarray) -> RayHits:
    """Nearest hit of each ray with the table and the objects.

    Args:
        scene: the scene (base frame, mm).
        origins_mm: (3,) one origin shared by all rays, or (N, 3) one per ray; base frame, mm.
        directions: (N, 3) float unit directions in the base frame.

    Returns:
        The nearest hits, see :class:`RayHits` (bit-identical to the numpy oracle,
        ``test/oracles/raycast_reference.py``).

    Raises:
        InputError: on wrongly shaped inputs.
    """
    o, d = _check_rays(origins_mm, directions)
    shared = o.ndim == 1
    comps = [np.ascontiguousarray(o[i:i + 1] if shared else o[:, i]) for i in range(3)]
    dirs = [np.ascontiguousarray(v, dtype=np.float64) for v in d.T]
    p = pack_scene(scene)
    t, normal, which = _cast_kernel(*comps, 0 if shared else 1, *dirs, p.table, p.kind,
                                    p.geom, p.height, p.planes, p.n_planes)
    ids = np.array([-1, 0] + [obj.scene_index for obj in scene.objects], dtype=np.int32)
    albedo = np.array([0.0, scene.table.albedo] + [obj.spec.albedo for obj in scene.objects])
    material = np.array([-1, scene.table.material_id]
                        + [obj.spec.material_id for obj in scene.objects], dtype=np.int32)
    which += 1
    return RayHits(t_mm=t, normal=normal, object_id=ids[which], albedo=albedo[which],
                   material_id=material[which])


def _check_rays(origins_mm: np.ndarray, directions: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Validated (origins as float64 (3,) or (N, 3) mm, directions (N, 3)) of a ray batch.

    Raises:
        InputError: on wrongly shaped inputs.
    """
    d = check_array("directions", directions, ndim=2, shape=(None, 3), dtype_kind="f")
    o = check_array("origins_mm", origins_mm, ndim=(1, 2), shape=(3,), dtype_kind="fiu")
    o = o.astype(np.float64, copy=False)
    if o.ndim == 2 and o.shape[0] != d.shape[0]:
        raise InputError(f"origins_mm: expected (3,) or ({d.shape[0]}, 3), got {o.shape}")
    return o, d


@lru_cache(maxsize=8)
def camera_rays(intrinsics: Intrinsics) -> np.ndarray:
    """Cached (H*W, 3) float64 unit pixel rays in the optical frame (read-only), the same as
    ``intrinsics.ray_directions().reshape(-1, 3)``."""
    rays = intrinsics.ray_directions().reshape(-1, 3)
    rays.flags.writeable = False
    return rays


def render_surface(scene: Scene, camera_to_base_mm: np.ndarray,
                   intrinsics: Intrinsics) -> SurfaceImage:
    """What each pixel centre of a camera sees.

    Args:
        scene: the scene (base frame, mm).
        camera_to_base_mm: (4, 4) float pose of the camera optical frame (x right, y down,
            z forward) in the base frame, translation in **mm**.
        intrinsics: the image grid to render; pass ``intrinsics.scaled(s)`` to supersample.

    Returns:
        A :class:`SurfaceImage`: radial range (mm), normals in the camera optical frame facing
        the camera, albedo, object and material ids; where the ray hits nothing: range and
        normal NaN, albedo 0, ids -1.
    """
    pose = check_array("camera_to_base_mm", camera_to_base_mm, ndim=2, shape=(4, 4),
                       dtype_kind="fiu").astype(np.float64, copy=False)
    rot = pose[:3, :3]
    rays_cam = camera_rays(intrinsics)
    hits = cast_rays(scene, pose[:3, 3], rotate(rays_cam, rot))
    normal_cam = rotate(hits.normal, rot.T)
    # Surfaces are seen from whichever side the camera is on.
    facing = np.sign(-np.einsum("ij,ij->i", normal_cam, rays_cam))
    normal_cam *= np.where(facing == 0, 1.0, facing)[:, None]
    shape = intrinsics.shape
    return SurfaceImage(
        range_mm=np.where(np.isfinite(hits.t_mm), hits.t_mm, np.nan).reshape(shape),
        normal=normal_cam.reshape(*shape, 3),
        albedo=hits.albedo.reshape(shape),
        object_id=hits.object_id.reshape(shape),
        material_id=hits.material_id.reshape(shape),
        intrinsics=intrinsics,
    )
