"""Diffuse multi-bounce light transport over a :class:`~.world.WorldModel`, as phasors.

The light is a spot at the camera centre; every surface patch it reaches re-emits diffusely, and
so, bounce after bounce, does every patch those reach. A pixel's indirect return is the light
arriving at its surface point x from all patches, times its albedo, carried back to the camera.
In the simulator's amplitude units (π × radiance, see :mod:`.phasor`), for a patch y of area A_y:

    E_1(y)    = P S(θ_y) cosθ_y^in / r_y² · V(light, y) · e^{ik r_y}                (irradiance)
    W_b(y)    = ρ_y / π · E_b(y) · A_y                                             (emission)
    E_{b+1}(z) = Σ_y W_b(y) · cosθ_z(y) cosθ_y(z) / (d_yz² + A_y/π) · V(y, z) · e^{ik d_yz}
    Z_ind(x)  = ρ_x e^{ik r_x} Σ_{b=1..B} E_{b+1}(x)

with k = 2π f / c per mm of *path*, S the spot's angular profile, V the visibility and A_y/π the
disc regularisation of the form factor for neighbouring patches. Each path keeps its own phase:
the total is k × (every leg's length), so longer detours shift the range more.

Speed comes from the patch hierarchy (:class:`~.world.SurfelTree`): a receiver takes a node's
aggregated emission when the node is small as seen from it (distance > ``open_ratio`` × its
radius) and nearly flat, and otherwise descends to its children; nodes wholly behind the
receiver's tangent plane, or facing away from it, are skipped as a whole. Bounces after the
first are gathered at nodes of about ``bounce_patch_mm`` (their irradiance is smooth); the
pixels gather at their own surface point. Visibility is exact against an analytic scene or
tested on depth maps (space carving), see :class:`~.world.WorldModel`.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ..raycast import PackedScene, segment_blocked
from ..surface import SurfaceImage
from .phasor import SPEED_OF_LIGHT_MM_S
from .rays import ray_directions

#: cosines below this count as zero: grazing pairs carry no light
MIN_COS = 1e-3
#: receivers and shadow-ray ends are moved this far off their surface (mm)
SURFACE_OFFSET_MM = 0.5
#: a node is gathered whole only when its normals differ by less than this (|n − n̄|)
MAX_SPREAD = 0.3
#: bounce receivers stay coarse where they get less than this share of the brightest one
REFINE_FRACTION = 0.02
#: coarse bounce patches are refined only within this many opening distances
#: (``open_ratio`` × radius) of the receiving pixels' surface
FOCUS_REACH = 2.0
#: neighbouring anchors whose irradiance magnitudes differ more than this factor are not
#: interpolated between
INTERPOLATION_SPREAD = 1.15
#: stack depth of the tree walk (tree depth is ~2 log2(leaves per face))
_STACK = 256


def pixel_area_mm2(surface: SurfaceImage, min_cos: float = 0.05) -> np.ndarray:
    """Surface area seen by each sample of ``surface``.

    Returns:
        (H, W) float64 area in mm² (NaN where no hit); incidence clipped at ``min_cos``.
    """
    rays = ray_directions(surface.intrinsics)
    cos_in = np.clip(-np.einsum("hwk,hwk->hw", surface.normal, rays), min_cos, 1.0)
    cos_axis = rays[..., 2]
    k = surface.intrinsics
    return surface.range_mm ** 2 * cos_axis ** 3 / (k.fx * k.fy * cos_in)


# --- visibility ----------------------------------------------------------------------------


@nb.njit(cache=True, inline="always")
def _occupied(px, py, pz, w2c, kin, depth, eps_mm, eps_rel):  # pragma: no cover - compiled
    """Space carving: behind the surface in every view that sees the point (and in ≥ 1)."""
    h = depth.shape[1]
    w = depth.shape[2]
    seen = False
    for v in range(w2c.shape[0]):
        cz = w2c[v, 2, 0] * px + w2c[v, 2, 1] * py + w2c[v, 2, 2] * pz + w2c[v, 2, 3]
        if not cz > 0.0:
            continue
        cx = w2c[v, 0, 0] * px + w2c[v, 0, 1] * py + w2c[v, 0, 2] * pz + w2c[v, 0, 3]
        cy = w2c[v, 1, 0] * px + w2c[v, 1, 1] * py + w2c[v, 1, 2] * pz + w2c[v, 1, 3]
        us = kin[v, 0] * cx / cz + kin[v, 2]
        vs = kin[v, 1] * cy / cz + kin[v, 3]
        if not (us > -0.5 and vs > -0.5 and us < w - 0.5 and vs < h - 0.5):
            continue
        d = depth[v, int(vs + 0.5), int(us + 0.5)]
        if not d < np.inf:
            continue
        lim = d + eps_mm + eps_rel * d
        if cx * cx + cy * cy + cz * cz <= lim * lim:
            return False
        seen = True
    return seen


@nb.njit(cache=True, inline="always")
def _in_height_field(px, py, pz, hf, hf_h, eps_mm):  # pragma: no cover - compiled
    """Below the support plane, or inside an object extruded down to it (see
    :class:`~.world.HeightField`: ``hf`` = origin, e1, e2, n (3 each), cell size)."""
    rx = px - hf[0]
    ry = py - hf[1]
    rz = pz - hf[2]
    up = hf[9] * rx + hf[10] * ry + hf[11] * rz
    if up < -eps_mm:
        return True
    i = math.floor((hf[3] * rx + hf[4] * ry + hf[5] * rz) / hf[12])
    j = math.floor((hf[6] * rx + hf[7] * ry + hf[8] * rz) / hf[12])
    if i < 0 or j < 0 or i >= hf_h.shape[0] or j >= hf_h.shape[1]:
        return False
    return up < hf_h[i, j] - eps_mm


@nb.njit(cache=True, inline="always")
def _blocked(ox, oy, oz, qx, qy, qz, end_margin, mode, table, kind, geom, height, planes,
             n_planes, w2c, kin, depth, eps_mm, eps_rel, step_mm, max_steps, skip_mm, hf,
             hf_h):  # pragma: no cover - compiled
    """Whether the segment o→q is blocked (mode 0: analytic scene, 1: depth views by space
    carving, 2: the height field of objects standing on a support plane)."""
    if mode == 0:
        return segment_blocked(ox, oy, oz, qx, qy, qz, 0.0, end_margin, table, kind, geom,
                               height, planes, n_planes)
    dx = qx - ox
    dy = qy - oy
    dz = qz - oz
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    steps = min(max_steps, int(length / step_mm))
    lo = skip_mm
    hi = length - skip_mm - end_margin
    for s in range(steps):
        t = (s + 1.0) / (steps + 1.0)
        tl = t * length
        if tl < lo or tl > hi:
            continue
        if mode == 2:
            if _in_height_field(ox + t * dx, oy + t * dy, oz + t * dz, hf, hf_h, 1.0):
                return True
        elif _occupied(ox + t * dx, oy + t * dy, oz + t * dz, w2c, kin, depth, eps_mm,
                       eps_rel):
            return True
    return False


@nb.njit(parallel=True, cache=True)
def _lit_kernel(points, normals, light, mode, table, kind, geom, height, planes, n_planes, w2c,
                kin, depth, eps_mm, eps_rel, step_mm, max_steps, skip_mm, hf,
                hf_h):  # pragma: no cover - compiled
    n = points.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    for i in nb.prange(n):
        px = points[i, 0] + SURFACE_OFFSET_MM * normals[i, 0]
        py = points[i, 1] + SURFACE_OFFSET_MM * normals[i, 1]
        pz = points[i, 2] + SURFACE_OFFSET_MM * normals[i, 2]
        out[i] = not _blocked(light[0], light[1], light[2], px, py, pz, 0.0, mode, table,
                              kind, geom, height, planes, n_planes, w2c, kin, depth, eps_mm,
                              eps_rel, step_mm, max_steps, skip_mm, hf, hf_h)
    return out


def _vis_args(scene: PackedScene | None, views, height_field=None) -> tuple:
    """The occluder as the compiled kernels' positional arguments (mode first)."""
    no_hf = (np.zeros(13), np.zeros((1, 1)))
    if scene is not None:
        return (0, scene.table, scene.kind, scene.geom, scene.height, scene.planes,
                scene.n_planes, np.zeros((0, 3, 4)), np.zeros((0, 4)), np.zeros((0, 1, 1)),
                2.0, 0.01, 4.0, 0, 3.0, *no_hf)
    hf = no_hf if height_field is None else (height_field.frame(), height_field.height_mm)
    return (1 if height_field is None else 2, *pack_empty(), views.world_to_camera,
            views.intrinsics, views.range_mm, float(views.eps_mm), float(views.eps_rel),
            float(views.step_mm), int(views.max_steps), float(views.skip_mm), *hf)


def pack_empty() -> tuple:
    """Analytic-scene arguments for a world without one (never read in mode 1)."""
    return (np.zeros(6), np.zeros(0, np.int64), np.zeros((0, 12)), np.zeros(0),
            np.zeros((0, 6, 4)), np.zeros(0, np.int64))


def shadow_test_scene(points: np.ndarray, normals: np.ndarray, light_mm: np.ndarray,
                      scene: PackedScene) -> np.ndarray:
    """(N,) bool: the points (N, 3) (mm, base frame) see the light at ``light_mm``."""
    args = _vis_args(scene, None)
    return _lit_kernel(points, normals, np.asarray(light_mm, np.float64), *args)


def shadow_test_views(points: np.ndarray, normals: np.ndarray, light_mm: np.ndarray,
                      views, height_field=None) -> np.ndarray:
    """(N,) bool: the points see the light, by space carving on ``views`` (a DepthViews) or,
    when given, in a :class:`~.world.HeightField`."""
    args = list(_vis_args(None, views, height_field))
    args[-4] = max(int(args[-4]), 64)  # a shadow ray is long: test it densely
    return _lit_kernel(points, normals, np.asarray(light_mm, np.float64), *args)


# --- gathering -----------------------------------------------------------------------------


@nb.njit(cache=True)
def _sum_up(w_re, w_im, w_abs, child, n_leaves):  # pragma: no cover - compiled
    for i in range(n_leaves, w_re.shape[0]):
        a = child[i, 0]
        b = child[i, 1]
        w_re[i] = w_re[a] + w_re[b]
        w_im[i] = w_im[a] + w_im[b]
        w_abs[i] = w_abs[a] + w_abs[b]


# One compiled loop nest (per receiver: walk the tree, refine or take each node): a call per
# node would cost numba a call frame in the innermost loop, and the cuts are its one state.
@nb.njit(parallel=True, fastmath={"nsz", "arcp", "contract", "afn", "reassoc"}, cache=True)
def _gather(rx_pos, rx_nrm, centre, normal, area, radius, spread, thickness, child, roots,
            w_re, w_im, w_abs, open2, max_spread, k_path, min_cos, mode, table, kind, geom,
            height, planes, n_planes, w2c, kin, depth, eps_mm, eps_rel, step_mm, max_steps,
            skip_mm, hf, hf_h):  # pragma: no cover - compiled
    """Irradiance phasor at each receiver point from the tree's emission (see module doc)."""
    n = rx_pos.shape[0]
    out_re = np.zeros(n)
    out_im = np.zeros(n)
    inv_pi = 1.0 / math.pi
    for i in nb.prange(n):
        stack = np.empty(_STACK, dtype=np.int64)
        x0 = rx_pos[i, 0]
        x1 = rx_pos[i, 1]
        x2 = rx_pos[i, 2]
        n0 = rx_nrm[i, 0]
        n1 = rx_nrm[i, 1]
        n2 = rx_nrm[i, 2]
        o0 = x0 + SURFACE_OFFSET_MM * n0
        o1 = x1 + SURFACE_OFFSET_MM * n1
        o2 = x2 + SURFACE_OFFSET_MM * n2
        acc_re = 0.0
        acc_im = 0.0
        # one root at a time: the stack then holds at most the tree's depth (a world can have
        # hundreds of faces, each a root)
        top = 0
        r = 0
        while top > 0 or r < roots.shape[0]:
            if top == 0:
                stack[0] = roots[r]
                top = 1
                r += 1
            top -= 1
            s = stack[top]
            if w_abs[s] <= 0.0:
                continue
            d0 = centre[s, 0] - x0
            d1 = centre[s, 1] - x1
            d2 = centre[s, 2] - x2
            dd = d0 * d0 + d1 * d1 + d2 * d2
            dist = math.sqrt(dd)
            rad = radius[s]
            # no point of the node passes a cosine test (each side's cosine carries a factor
            # |p − x| ≥ dist − rad): the node is skipped whole. Receiver side:
            # n_x·(p − x) ≤ n_x·(c − x) + |n_x·n̄| h + sin∠(n_x, n̄) R
            floor = min_cos * max(dist - rad, 0.0)
            cos_x = n0 * d0 + n1 * d1 + n2 * d2
            dot = n0 * normal[s, 0] + n1 * normal[s, 1] + n2 * normal[s, 2]
            sin = math.sqrt(max(0.0, 1.0 - dot * dot))
            if cos_x + abs(dot) * thickness[s] + (sin + spread[s]) * rad <= floor:
                continue
            # sender side: n_y·(x − p) ≤ n̄·(x − c) + h + spread (|x − c| + R)
            nd = -(normal[s, 0] * d0 + normal[s, 1] * d1 + normal[s, 2] * d2)
            if nd + thickness[s] + spread[s] * (dist + rad) <= floor:
                continue
            if child[s, 0] >= 0 and (dd < open2 * rad * rad or spread[s] > max_spread):
                if top + 2 > _STACK:
                    continue  # cannot happen for trees of sane depth
                stack[top] = child[s, 0]
                stack[top + 1] = child[s, 1]
                top += 2
                continue
            if cos_x <= min_cos * dist or nd <= min_cos * dist:
                continue
            if _blocked(o0, o1, o2, centre[s, 0], centre[s, 1], centre[s, 2],
                        thickness[s] + SURFACE_OFFSET_MM, mode, table, kind, geom, height,
                        planes, n_planes, w2c, kin, depth, eps_mm, eps_rel, step_mm,
                        max_steps, skip_mm, hf, hf_h):
                continue
            g = cos_x * nd / (dd * (dd + area[s] * inv_pi))
            ph = k_path * dist
            c = math.cos(ph)
            sn = math.sin(ph)
            acc_re += g * (w_re[s] * c - w_im[s] * sn)
            acc_im += g * (w_re[s] * sn + w_im[s] * c)
        out_re[i] = acc_re
        out_im[i] = acc_im
    return out_re, out_im


@nb.njit(cache=True)
def _bounce_cut(radius, spread, child, n_leaves, max_radius, max_spread):  # pragma: no cover
    """For every leaf, its highest ancestor that is small and flat (a bounce receiver).

    Returns:
        (n_leaves,) int64 receiver node per leaf; (N,) bool which nodes are receivers.
    """
    n = radius.shape[0]
    parent = np.full(n, -1, dtype=np.int64)
    for i in range(n_leaves, n):
        parent[child[i, 0]] = i
        parent[child[i, 1]] = i
    cut = np.empty(n_leaves, dtype=np.int64)
    is_rx = np.zeros(n, dtype=np.bool_)
    for leaf in range(n_leaves):
        node = leaf
        while True:
            p = parent[node]
            if p < 0 or radius[p] > max_radius or spread[p] > max_spread:
                break
            node = p
        cut[leaf] = node
        is_rx[node] = True
    return cut, is_rx


def _gather_tree(rx_pos, rx_nrm, tree, w: np.ndarray, k_path: float, open_ratio: float,
                 vis: tuple) -> np.ndarray:
    """(M,) complex128 irradiance phasor at the receivers from leaf emission ``w``."""
    n = tree.size
    w_re = np.zeros(n)
    w_im = np.zeros(n)
    w_abs = np.zeros(n)
    w_re[:tree.n_leaves] = w.real
    w_im[:tree.n_leaves] = w.imag
    w_abs[:tree.n_leaves] = np.abs(w)
    _sum_up(w_re, w_im, w_abs, tree.child, tree.n_leaves)
    re, im = _gather(np.ascontiguousarray(rx_pos), np.ascontiguousarray(rx_nrm), tree.centre,
                     tree.normal, tree.area, tree.radius, tree.spread, tree.thickness,
                     tree.child, tree.roots, w_re, w_im, w_abs, float(open_ratio) ** 2,
                     MAX_SPREAD, k_path, MIN_COS, *vis)
    return re + 1j * im


def first_bounce_emission(world, mod_freq_hz: float, light_power: float) -> np.ndarray:
    """(n_leaves,) complex128 W_1: what each leaf re-emits of the light it receives directly.

    Units amplitude·mm² (see the module docstring); 0 for unlit leaves.
    """
    tree = world.tree
    from .world import spot_profile
    p = tree.centre[:tree.n_leaves] - world.light.position
    r = np.linalg.norm(p, axis=1)
    u = p / r[:, None]
    cos_in = np.clip(-np.einsum("ij,ij->i", tree.normal[:tree.n_leaves], u), 0.0, 1.0)
    profile = spot_profile(u @ world.light.axis, world.light.cutoff_deg, world.light.beam_deg)
    lit = world.lit if world.lit is not None else np.ones(tree.n_leaves, bool)
    k_path = 2.0 * math.pi * mod_freq_hz / SPEED_OF_LIGHT_MM_S
    e1 = np.where(lit, light_power * profile * cos_in / r ** 2, 0.0)
    return (tree.albedo[:tree.n_leaves] / math.pi * tree.area[:tree.n_leaves] * e1
            * np.exp(1j * k_path * r))


def bounce_emissions(world, *, mod_freq_hz: float, light_power: float, bounces: int,
                     open_ratio: float = 3.0, bounce_patch_mm: float = 8.0,
                     focus_mm: np.ndarray | None = None) -> list[np.ndarray]:
    """Leaf emission of each bounce, W_1 .. W_B (each (n_leaves,) complex128, amplitude·mm²).

    ``focus_mm``: (M, 3) world points (mm) where the light is wanted in the end (the pixels'
    surface), or None (everywhere). Coarse patches farther from all of them than
    :data:`FOCUS_REACH` × ``open_ratio`` × their radius are not refined: every gather there
    takes them (or an ancestor) whole, so only their sum counts, which the coarse pass gives
    to second order. The third and later bounces are gathered at the coarse patches only.
    """
    tree = world.tree
    k_path = 2.0 * math.pi * mod_freq_hz / SPEED_OF_LIGHT_MM_S
    vis = _vis_args(world.scene, world.views, world.height_field)
    out = [first_bounce_emission(world, mod_freq_hz, light_power)]
    if bounces < 2:
        return out
    # receivers: patches of about bounce_patch_mm (radius of a square: side / √2), and
    # patches 4× larger where the coarse pass finds little light
    fine, _ = _bounce_cut(tree.radius, tree.spread, tree.child, tree.n_leaves,
                          1.01 * bounce_patch_mm / math.sqrt(2.0), MAX_SPREAD)
    coarse, _ = _bounce_cut(tree.radius, tree.spread, tree.child, tree.n_leaves,
                            4.04 * bounce_patch_mm / math.sqrt(2.0), MAX_SPREAD)
    leaf_factor = tree.albedo[:tree.n_leaves] / math.pi * tree.area[:tree.n_leaves]
    refinable = None
    if focus_mm is not None and len(focus_mm):
        from scipy.spatial import cKDTree

        patches = np.unique(coarse)
        dist, _ = cKDTree(np.asarray(focus_mm, np.float64)).query(tree.centre[patches])
        refinable = np.zeros(tree.size, dtype=bool)
        refinable[patches] = (dist <= FOCUS_REACH * open_ratio * tree.radius[patches]
                              + bounce_patch_mm)
    nowhere = np.zeros(tree.size, dtype=bool)
    for b in range(bounces - 1):
        # light that has bounced twice is smooth: the coarse patches resolve it
        e = _adaptive_irradiance(tree, out[-1], fine, coarse, k_path, open_ratio, vis,
                                 refinable if b == 0 else nowhere)
        out.append(leaf_factor * e)
    return out


def _adaptive_irradiance(tree, w: np.ndarray, fine: np.ndarray, coarse: np.ndarray,
                         k_path: float, open_ratio: float, vis: tuple,
                         refinable: np.ndarray | None = None) -> np.ndarray:
    """(n_leaves,) complex128 irradiance phasor per leaf from emission ``w``: gathered at the
    coarse patches, then again at the fine ones inside every coarse patch that receives more
    than ``REFINE_FRACTION`` of the brightest one's irradiance (and, with ``refinable``
    (nodes,) bool, is one of those)."""
    rx_c, slot_c = np.unique(coarse, return_inverse=True)
    e_c = _gather_tree(tree.centre[rx_c], tree.normal[rx_c], tree, w, k_path, open_ratio, vis)
    mag = np.abs(e_c)
    refine_patch = mag > REFINE_FRACTION * (mag.max() if mag.size else 0.0)
    if refinable is not None:
        refine_patch &= refinable[rx_c]
    e = e_c[slot_c]
    leaves = np.flatnonzero(refine_patch[slot_c])
    if leaves.size:
        rx_f, slot_f = np.unique(fine[leaves], return_inverse=True)
        e_f = _gather_tree(tree.centre[rx_f], tree.normal[rx_f], tree, w, k_path, open_ratio,
                           vis)
        e[leaves] = e_f[slot_f]
    return e


def _snap_to_plane(pos: np.ndarray, nrm: np.ndarray, plane: np.ndarray,
                   max_tilt_deg: float = 25.0) -> tuple[np.ndarray, np.ndarray]:
    """Receivers lying on ``plane`` (n, d) and facing like it, moved onto it with its normal."""
    n, d = plane[:3], plane[3]
    signed = pos @ n - d
    on = (np.abs(signed) <= 2.0 + 0.005 * np.linalg.norm(pos, axis=1)) & \
        (nrm @ n >= math.cos(math.radians(max_tilt_deg)))
    pos = np.where(on[:, None], pos - signed[:, None] * n, pos)
    nrm = np.where(on[:, None], n, nrm)
    return pos, nrm


def _interpolable(rx_pos: np.ndarray, rx_nrm: np.ndarray, valid: np.ndarray
                  ) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    """Which pixels take their irradiance from neighbouring anchors (even row and column).

    A pixel is interpolated when every anchor around it (2 along a row or column, 4 on the
    diagonals) is a receiver on the same smooth surface: normals within ~10° and points within
    2 mm + 1 % of each other. Elsewhere (depth edges, creases, the crop's border) it is
    gathered itself.

    Args:
        rx_pos, rx_nrm: (H, W, 3) receiver points and normals (NaN where not a receiver).
        valid: (H, W) bool receivers.

    Returns:
        anchors: (H, W) bool the pixels gathered first.
        groups: per parity class, ((A, 2) int (dv, du) offsets to its anchors, (H, W) bool the
            pixels that take the mean of those anchors).
    """
    h, w = valid.shape
    v, u = np.mgrid[0:h, 0:w]
    anchors = valid & (v % 2 == 0) & (u % 2 == 0)
    groups = []
    for parity, offsets in (((1, 0), [(-1, 0), (1, 0)]), ((0, 1), [(0, -1), (0, 1)]),
                            ((1, 1), [(-1, -1), (-1, 1), (1, -1), (1, 1)])):
        pick = valid & (v % 2 == parity[0]) & (u % 2 == parity[1])
        ok = pick.copy()
        for dv, du in offsets:
            vv = np.clip(v + dv, 0, h - 1)
            uu = np.clip(u + du, 0, w - 1)
            inside = (v + dv >= 0) & (v + dv < h) & (u + du >= 0) & (u + du < w)
            same = anchors[vv, uu] & inside
            dn = np.einsum("hwk,hwk->hw", rx_nrm, rx_nrm[vv, uu])
            gap = np.linalg.norm(rx_pos - rx_pos[vv, uu], axis=-1)
            scale = 2.0 + 0.01 * np.linalg.norm(rx_pos, axis=-1)
            ok &= same & (np.nan_to_num(dn) > 0.985) & (np.nan_to_num(gap, nan=np.inf)
                                                          <= scale * 2.5)
        groups.append((np.array(offsets), ok))
    return anchors, groups


def indirect_phasor(surface: SurfaceImage, world, *, mod_freq_hz: float, light_power: float,
                    bounces: int = 3, open_ratio: float = 3.0, bounce_patch_mm: float = 8.0,
                    receivers: np.ndarray | None = None,
                    interpolate: bool = True) -> np.ndarray:
    """Indirect phasor arriving at every pixel of ``surface`` through ``bounces`` bounces.

    Args:
        surface: pixel-resolution surface image (the receivers: centre rays of the pixels).
        world: the :class:`~.world.WorldModel` the light travels through (its
            ``camera_to_world`` places ``surface`` in it).
        mod_freq_hz: modulation frequency in Hz.
        light_power: P in amplitude·mm².
        bounces: diffuse bounces between the light and the receiving pixel (1 = one bounce).
        open_ratio: a node is gathered whole when farther than this many radii.
        bounce_patch_mm: patch size at which bounces after the first are gathered, mm.
        receivers: (H, W) bool, the pixels whose indirect light is computed (None = all); the
            others get 0.
        interpolate: gather at every other pixel of each row and column and interpolate the
            irradiance between them on smooth surfaces (about 3× faster; see
            :func:`_interpolable`), gathering the rest — edges and creases — themselves.

    Returns:
        (H, W) complex128 indirect phasor (same amplitude units as the direct return); 0 where
        the pixel has no hit.
    """
    h, w = surface.intrinsics.shape
    out = np.zeros((h, w), dtype=np.complex128)
    # every pixel with a surface places the anchors, so a receiver's value does not depend on
    # which other pixels are receivers
    surfaced = surface.valid & np.all(np.isfinite(surface.normal), axis=-1)
    valid = surfaced if receivers is None else surfaced & np.asarray(receivers, dtype=bool)
    if not valid.any() or bounces < 1:
        return out
    pose = world.camera_to_world
    points = ray_directions(surface.intrinsics) * surface.range_mm[..., None]
    rx_pos = np.where(surfaced[..., None], points @ pose[:3, :3].T + pose[:3, 3], np.nan)
    # refined near every pixel with a surface (not only the receivers), for the same reason
    emissions = bounce_emissions(world, mod_freq_hz=mod_freq_hz, light_power=light_power,
                                 bounces=bounces, open_ratio=open_ratio,
                                 bounce_patch_mm=bounce_patch_mm, focus_mm=rx_pos[surfaced])
    total = np.sum(emissions, axis=0)
    rx_nrm = np.where(surfaced[..., None], surface.normal @ pose[:3, :3].T, np.nan)
    if world.support_plane is not None:
        rx_pos[surfaced], rx_nrm[surfaced] = _snap_to_plane(rx_pos[surfaced],
                                                            rx_nrm[surfaced],
                                                            world.support_plane)
    k_path = 2.0 * math.pi * mod_freq_hz / SPEED_OF_LIGHT_MM_S
    vis = _vis_args(world.scene, world.views, world.height_field)
    irradiance = np.zeros((h, w), dtype=np.complex128)
    todo = valid
    if interpolate:
        anchors, groups = _interpolable(rx_pos, rx_nrm, surfaced)
        # the anchors the receivers use: themselves and their 8 neighbours'
        near_rx = np.zeros((h + 2, w + 2), dtype=bool)
        for dv in range(3):
            for du in range(3):
                near_rx[dv:dv + h, du:du + w] |= valid
        used = anchors & near_rx[1:h + 1, 1:w + 1]
        irradiance[used] = _gather_tree(rx_pos[used], rx_nrm[used], world.tree, total, k_path,
                                        open_ratio, vis)
        todo = valid & ~anchors
        v, u = np.mgrid[0:h, 0:w]
        for offsets, ok in groups:
            ok = ok & valid
            vv, uu = v[ok], u[ok]
            near = np.array([irradiance[vv + dv, uu + du] for dv, du in offsets])
            mag = np.abs(near)
            # where the anchors disagree the field is steep (near a crease): gather instead
            smooth = mag.max(axis=0) <= INTERPOLATION_SPREAD * mag.min(axis=0) + 1e-12 * \
                (1.0 + mag.max(axis=0))
            irradiance[vv[smooth], uu[smooth]] = near[:, smooth].mean(axis=0)
            ok[vv[~smooth], uu[~smooth]] = False
            todo = todo & ~ok
    if todo.any():
        irradiance[todo] = _gather_tree(rx_pos[todo], rx_nrm[todo], world.tree, total, k_path,
                                        open_ratio, vis)
    r = np.where(valid, surface.range_mm, 0.0)
    out[valid] = (surface.albedo * np.exp(1j * k_path * r) * irradiance)[valid]
    return out


__all__ = ["bounce_emissions", "first_bounce_emission", "indirect_phasor", "pixel_area_mm2",
           "shadow_test_scene", "shadow_test_views"]
