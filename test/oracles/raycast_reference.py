"""The plain-numpy ray caster: the test oracle that keeps the package's one ray caster honest.

:func:`cast_rays_reference` evaluates, all rays at once with a Python loop over the objects,
exactly the floating-point expressions the compiled kernel of
:func:`tof_mpd_ros.sim.raycast.cast_rays` evaluates per ray, in the same order, so the two give
bit-identical hits (``test/sim/test_fast_paths.py``). :func:`visible_from` is the step-by-step
projector visibility that the compiled SL kernel (:func:`~tof_mpd_ros.sim.raycast.sl_ranges`)
fuses into its pass. Not shipped in the wheel: it lives under ``test/`` (importable as
``oracles.raycast_reference`` because pytest puts ``test/`` on ``sys.path`` for its root
``conftest.py``).

Units: origins, hit distances and the scene in **millimetres**, base frame; directions are unit
vectors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tof_mpd_ros.sim.objects import ObjectSpec
from tof_mpd_ros.sim.raycast import T_MIN_MM, RayHits, _check_rays, cast_rays
from tof_mpd_ros.sim.scene import PlacedObject, Scene, Table
from tof_mpd_ros.validation import check_array


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


def cast_rays_reference(scene: Scene, origins_mm: np.ndarray,
                        directions: np.ndarray) -> RayHits:
    """:func:`~tof_mpd_ros.sim.raycast.cast_rays` in plain numpy (all rays at once, a loop over
    the objects): its test oracle.

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


def visible_from(scene: Scene, points_mm: np.ndarray, origin_mm: np.ndarray,
                 tol_mm: float = 1.0) -> np.ndarray:
    """Which surface points a point-like viewer (a projector, a light) sees unoccluded: one
    :func:`~tof_mpd_ros.sim.raycast.cast_rays` from the viewer to every point.

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
