"""Analytic ray casting of a :class:`~tof_mpd_ros.sim.scene.Scene`.

:func:`cast_rays` packs the scene into flat arrays and runs one compiled (numba) kernel over the
rays in parallel; per ray it tests the table and then each object, culled by its bounding sphere.
The kernel evaluates exactly the same floating-point expressions, in the same order, as the
plain-numpy implementation :func:`cast_rays_reference` (all rays at once, a Python loop over the
objects), which is kept as the test oracle: both give bit-identical hits.

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
from .objects import ObjectSpec
from .scene import PlacedObject, Scene, Table
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


@dataclass
class _Rays:
    """Rays as components, so every step is an elementwise numpy operation.

    Origins are floats when all rays share one origin, else (M,) arrays; directions are (M,)
    contiguous arrays (unit vectors). Units: mm.
    """

    ox: float | np.ndarray
    oy: float | np.ndarray
    oz: float | np.ndarray
    dx: np.ndarray
    dy: np.ndarray
    dz: np.ndarray

    def take(self, idx: np.ndarray) -> _Rays:
        """The subset of rays ``idx`` ((K,) int); a shared origin stays shared."""
        ox, oy, oz = (v if np.ndim(v) == 0 else v[idx] for v in (self.ox, self.oy, self.oz))
        return _Rays(ox, oy, oz, self.dx[idx], self.dy[idx], self.dz[idx])

    def to_object(self, obj: PlacedObject) -> _Rays:
        """The same rays in ``obj``'s frame (objects only turn about z)."""
        c, s = np.cos(obj.yaw_rad), np.sin(obj.yaw_rad)
        x, y = self.ox - obj.x_mm, self.oy - obj.y_mm
        return _Rays(c * x + s * y, c * y - s * x, self.oz - obj.z_mm,
                     c * self.dx + s * self.dy, c * self.dy - s * self.dx, self.dz)


Normal = tuple[np.ndarray, np.ndarray, np.ndarray]


def _dot(n: np.ndarray, x: float | np.ndarray, y: float | np.ndarray,
         z: float | np.ndarray) -> float | np.ndarray:
    """n . (x, y, z), skipping zero coefficients (most faces are axis-aligned)."""
    terms = [c * v for c, v in zip(n, (x, y, z), strict=True) if c != 0.0]
    return sum(terms[1:], terms[0]) if terms else 0.0


def _hit_polyhedron(r: _Rays, normals: np.ndarray,
                    offsets: np.ndarray) -> tuple[np.ndarray, Normal]:
    """Entry into the convex set ``normals @ x <= offsets`` (Kay-Kajiya slabs), object frame.

    Args:
        r: M rays in the object frame.
        normals: (K, 3) outward unit plane normals; offsets: (K,) mm.

    Returns:
        t: (M,) entry distance, mm (inf = miss); the outward normal at the entry as three (M,)
        components.
    """
    m = r.dx.size
    t_in, t_out = np.full(m, -np.inf), np.full(m, np.inf)
    k_in = np.zeros(m, dtype=np.intp)
    open_ = np.ones(m, dtype=bool)
    for k, (normal, offset) in enumerate(zip(normals, offsets, strict=True)):
        denom = _dot(normal, r.dx, r.dy, r.dz)
        inside_by = offset - _dot(normal, r.ox, r.oy, r.oz)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = inside_by / denom
        entering = (denom < 0) & (t > t_in)
        t_in = np.where(entering, t, t_in)
        k_in[entering] = k
        t_out = np.where((denom > 0) & (t < t_out), t, t_out)
        # A ray parallel to a face and outside it never enters.
        open_ &= (denom != 0) | (inside_by >= 0)
    hit = open_ & (t_in <= t_out) & (t_in > T_MIN_MM)
    n = normals[k_in]
    return np.where(hit, t_in, np.inf), (n[:, 0], n[:, 1], n[:, 2])


def _slab_z(r: _Rays, top: float) -> tuple[np.ndarray, np.ndarray]:
    """Interval of t (mm) where the ray is inside 0 <= z <= top; empty as (inf, -inf)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = -r.oz / r.dz
        t1 = (top - r.oz) / r.dz
    flat = r.dz == 0
    inside = (r.oz >= 0) & (r.oz <= top)
    lo = np.where(flat, np.where(inside, -np.inf, np.inf), np.minimum(t0, t1))
    hi = np.where(flat, np.where(inside, np.inf, -np.inf), np.maximum(t0, t1))
    return lo, hi


def _hit_cylinder(r: _Rays, radius: float, height: float) -> tuple[np.ndarray, Normal]:
    """Entry into the upright cylinder x^2 + y^2 <= r^2, 0 <= z <= h (object frame, mm).

    Same returns as :func:`_hit_polyhedron`.
    """
    a = r.dx**2 + r.dy**2
    b = r.ox * r.dx + r.oy * r.dy
    c = r.ox**2 + r.oy**2 - radius**2
    disc = b * b - a * c
    root = np.sqrt(np.maximum(disc, 0.0))
    vertical = a < 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        side_lo = np.where(vertical, np.where(c <= 0, -np.inf, np.inf), (-b - root) / a)
        side_hi = np.where(vertical, np.where(c <= 0, np.inf, -np.inf), (-b + root) / a)
    side_lo = np.where(disc < 0, np.inf, side_lo)
    cap_lo, cap_hi = _slab_z(r, height)
    t_in = np.maximum(side_lo, cap_lo)
    hit = (t_in <= np.minimum(side_hi, cap_hi)) & (t_in > T_MIN_MM)
    t_safe = np.where(hit, t_in, 0.0)
    on_side = side_lo >= cap_lo
    nx = np.where(on_side, (r.ox + t_safe * r.dx) / radius, 0.0)
    ny = np.where(on_side, (r.oy + t_safe * r.dy) / radius, 0.0)
    nz = np.where(on_side, 0.0, -np.sign(r.dz))
    return np.where(hit, t_in, np.inf), (nx, ny, nz)


def _hit_sphere(r: _Rays, radius: float) -> tuple[np.ndarray, Normal]:
    """Entry into the sphere of ``radius`` centred at (0, 0, radius) (resting on z = 0).

    Same returns as :func:`_hit_polyhedron`.
    """
    ocz = r.oz - radius
    b = r.ox * r.dx + r.oy * r.dy + ocz * r.dz
    c = r.ox**2 + r.oy**2 + ocz**2 - radius**2
    disc = b * b - c
    t_in = -b - np.sqrt(np.maximum(disc, 0.0))
    hit = (disc >= 0) & (t_in > T_MIN_MM)
    t_safe = np.where(hit, t_in, 0.0)
    normal = ((r.ox + t_safe * r.dx) / radius, (r.oy + t_safe * r.dy) / radius,
              (ocz + t_safe * r.dz) / radius)
    return np.where(hit, t_in, np.inf), normal


def _hit_local(spec: ObjectSpec, r: _Rays) -> tuple[np.ndarray, Normal]:
    """Dispatch on the object's kind; rays and results in the object frame."""
    if spec.kind in ("box", "prism"):
        return _hit_polyhedron(r, *spec.polyhedron_planes())
    if spec.kind == "cylinder":
        return _hit_cylinder(r, spec.dims_mm[0] / 2.0, spec.dims_mm[2])
    return _hit_sphere(r, spec.dims_mm[0] / 2.0)


def _near_sphere(r: _Rays, centre: np.ndarray, radius: float) -> np.ndarray:
    """(N,) bool: the ray passes within ``radius`` of ``centre`` ahead of its origin."""
    cx, cy, cz = centre[0] - r.ox, centre[1] - r.oy, centre[2] - r.oz
    along = cx * r.dx + cy * r.dy + cz * r.dz
    dist2 = cx * cx + cy * cy + cz * cz - along * along
    return (dist2 <= radius**2) & (along + radius > 0)


def _hit_table(table: Table, r: _Rays) -> np.ndarray:
    """(N,) distance (mm) to the table rectangle, inf = miss; rays from either side count."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (table.height_mm - r.oz) / r.dz
    t_safe = np.where(np.isfinite(t), t, 0.0)
    inside = ((np.abs(r.ox + t_safe * r.dx - table.centre_xy_mm[0]) <= table.half_extent_mm[0])
              & (np.abs(r.oy + t_safe * r.dy - table.centre_xy_mm[1])
                 <= table.half_extent_mm[1]))
    return np.where(inside & (t > T_MIN_MM), t, np.inf)


def _apply_object(obj: PlacedObject, rays: _Rays, hits: RayHits) -> None:
    """Intersect ``obj`` and keep, in place, whichever of it and ``hits`` is nearer."""
    centre, radius = obj.bounding_sphere()
    idx = np.flatnonzero(_near_sphere(rays, centre, radius))
    if idx.size == 0:
        return
    t, (nx, ny, nz) = _hit_local(obj.spec, rays.take(idx).to_object(obj))
    nearer = t < hits.t_mm[idx]
    sel = idx[nearer]
    c, s = np.cos(obj.yaw_rad), np.sin(obj.yaw_rad)
    nx, ny, nz = nx[nearer], ny[nearer], nz[nearer]
    hits.t_mm[sel] = t[nearer]
    hits.normal[sel] = np.stack([c * nx - s * ny, s * nx + c * ny, nz], axis=1)
    hits.object_id[sel] = obj.scene_index
    hits.albedo[sel] = obj.spec.albedo
    hits.material_id[sel] = obj.spec.material_id


_KIND_CODES = {"box": 0, "prism": 0, "cylinder": 1, "sphere": 2}
# planes per polyhedron (a box has 6, a prism 5)
_MAX_PLANES = 6


@dataclass(frozen=True)
class PackedScene:
    """The scene as flat arrays for the kernel (object k of the arrays = ``scene.objects[k]``).

    Attributes:
        table: (6,) height, centre x, centre y, half extent x, half extent y (mm), albedo.
        kind: (K,) int64 0 = polyhedron, 1 = cylinder, 2 = sphere.
        geom: (K, 12) float64 x, y, z (mm), cos yaw, sin yaw, bounding-sphere centre x, y, z,
            its radius squared, shape radius (cylinder, sphere), shape radius squared,
            bounding-sphere radius.
        height: (K,) float64 cylinder height, mm.
        planes: (K, 6, 4) float64 polyhedron planes (normal, offset); ``n_planes`` (K,) used.
    """

    table: np.ndarray
    kind: np.ndarray
    geom: np.ndarray
    height: np.ndarray
    planes: np.ndarray
    n_planes: np.ndarray


def pack_scene(scene: Scene) -> PackedScene:
    """Flatten ``scene`` for :func:`_cast_kernel` (the same scalars the numpy oracle uses)."""
    t = scene.table
    table = np.array([t.height_mm, t.centre_xy_mm[0], t.centre_xy_mm[1], t.half_extent_mm[0],
                      t.half_extent_mm[1], t.albedo], dtype=np.float64)
    k = len(scene.objects)
    kind = np.zeros(k, dtype=np.int64)
    geom = np.zeros((k, 12))
    height = np.zeros(k)
    planes = np.zeros((k, _MAX_PLANES, 4))
    n_planes = np.zeros(k, dtype=np.int64)
    for i, obj in enumerate(scene.objects):
        spec = obj.spec
        kind[i] = _KIND_CODES[spec.kind]
        centre, radius = obj.bounding_sphere()
        shape_r = spec.dims_mm[0] / 2.0
        geom[i] = [obj.x_mm, obj.y_mm, obj.z_mm, np.cos(obj.yaw_rad), np.sin(obj.yaw_rad),
                   centre[0], centre[1], centre[2], radius**2, shape_r, shape_r**2, radius]
        height[i] = spec.dims_mm[2]
        if kind[i] == 0:
            normals, offsets = spec.polyhedron_planes()
            n_planes[i] = len(offsets)
            planes[i, :len(offsets), :3] = normals
            planes[i, :len(offsets), 3] = offsets
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
        a = planes[k, 0]
        b = planes[k, 1]
        c = planes[k, 2]
        denom = _dot3(a, b, c, dx, dy, dz)
        inside_by = planes[k, 3] - _dot3(a, b, c, ox, oy, oz)
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
    c = g[3]
    s = g[4]
    x = ox - g[0]
    y = oy - g[1]
    lox = c * x + s * y
    loy = c * y - s * x
    loz = oz - g[2]
    ldx = c * dx + s * dy
    ldy = c * dy - s * dx
    if kind[k] == 0:
        tk, kp = _kernel_polyhedron(planes[k], n_planes[k], lox, loy, loz, ldx, ldy, dz)
        return tk, planes[k, kp, 0], planes[k, kp, 1], planes[k, kp, 2]
    if kind[k] == 1:
        return _kernel_cylinder(g[9], g[10], height[k], lox, loy, loz, ldx, ldy, dz)
    return _kernel_sphere(g[9], g[10], lox, loy, loz, ldx, ldy, dz)


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
    t = (table[0] - oz) / dz
    if ((t - t) == 0.0 and t > T_MIN_MM and abs(ox + t * dx - table[1]) <= table[3]
            and abs(oy + t * dy - table[2]) <= table[4]):
        best = t
        nx_b = 0.0
        ny_b = 0.0
        nz_b = 1.0
        which = 0
    for k in range(kind.shape[0]):
        g = geom[k]
        # bounding-sphere cull in the base frame
        cx = g[5] - ox
        cy = g[6] - oy
        cz = g[7] - oz
        along = cx * dx + cy * dy + cz * dz
        dist2 = cx * cx + cy * cy + cz * cz - along * along
        if not (dist2 <= g[8] and along + g[11] > 0.0):
            continue
        c = g[3]
        s = g[4]
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
    t = (table[0] - oz) / dz
    if ((t - t) == 0.0 and t > t_lo and t < t_hi and abs(ox + t * dx - table[1]) <= table[3]
            and abs(oy + t * dy - table[2]) <= table[4]):
        return True
    for k in range(kind.shape[0]):
        g = geom[k]
        cx = g[5] - ox
        cy = g[6] - oy
        cz = g[7] - oz
        along = cx * dx + cy * dy + cz * dz
        dist2 = cx * cx + cy * cy + cz * cz - along * along
        if not (dist2 <= g[8] and along + g[11] > t_lo and along - g[11] < t_hi):
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
        The nearest hits, see :class:`RayHits` (bit-identical to :func:`cast_rays_reference`).

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


def cast_rays_reference(scene: Scene, origins_mm: np.ndarray,
                        directions: np.ndarray) -> RayHits:
    """:func:`cast_rays` in plain numpy (all rays at once, a loop over objects): the test oracle.

    Args:
        scene: the scene (base frame, mm).
        origins_mm: (3,) one origin shared by all rays, or (N, 3) one per ray; base frame, mm.
        directions: (N, 3) float unit directions in the base frame.

    Returns:
        The nearest hits, see :class:`RayHits`.

    Raises:
        InputError: on wrongly shaped inputs.
    """
    o, d = _check_rays(origins_mm, directions)
    comps = [float(v) for v in o] if o.ndim == 1 else [np.ascontiguousarray(v) for v in o.T]
    dirs = [np.ascontiguousarray(v, dtype=np.float64) for v in d.T]
    rays = _Rays(*comps, *dirs)
    t_table = _hit_table(scene.table, rays)
    on_table = np.isfinite(t_table)
    hits = RayHits(
        t_mm=t_table,
        normal=np.where(on_table[:, None], np.array([0.0, 0.0, 1.0]), np.nan),
        object_id=np.where(on_table, 0, -1).astype(np.int32),
        albedo=np.where(on_table, scene.table.albedo, 0.0),
        material_id=np.where(on_table, scene.table.material_id, -1).astype(np.int32),
    )
    for obj in scene.objects:
        _apply_object(obj, rays, hits)
    return hits


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


def visible_from(scene: Scene, points_mm: np.ndarray, origin_mm: np.ndarray,
                 tol_mm: float = 1.0) -> np.ndarray:
    """Which surface points a point-like viewer (a projector, a light) sees unoccluded.

    Args:
        scene: the scene (base frame, mm).
        points_mm: (N, 3) float points on scene surfaces, base frame, mm; NaN rows -> False.
        origin_mm: (3,) viewer position, base frame, mm.
        tol_mm: a point counts as visible when the first hit along the ray from the origin is
            no nearer than its distance minus this tolerance (mm).

    Returns:
        (N,) bool.
    """
    p = check_array("points_mm", points_mm, ndim=2, shape=(None, 3), dtype_kind="fiu")
    origin = check_array("origin_mm", origin_mm, ndim=1, shape=(3,), dtype_kind="fiu")
    finite = np.isfinite(p).all(axis=1)
    offset = np.where(finite[:, None], p - origin, np.array([0.0, 0.0, -1.0]))
    dist = np.linalg.norm(offset, axis=1)
    ok = finite & (dist > 0)
    dirs = offset / np.where(dist > 0, dist, 1.0)[:, None]
    hits = cast_rays(scene, origin.astype(np.float64), dirs)
    return ok & (hits.t_mm >= dist - tol_mm)
