"""One-bounce diffuse light transport (camera → y → x → camera) over the visible surface.

With the light source at the camera centre the lit surface is exactly the camera-visible surface,
so the first indirect bounce is computable from the visible surface alone. For a receiver x and a
sender patch y (area A_y), in the simulator's amplitude units (π × radiance, see :mod:`.phasor`):

    Z_ind(x) = ρ_x e^{ik r_x} Σ_y  (ρ_y/π) P cosθ_y^in / r_y² · A_y
                                  · cosθ_x(y) cosθ_y(x) / (d_xy² + A_y/π) · V(x, y) · e^{ik d_xy}

with k = 2π f / c per mm of *path* (so the total phase is k (r_y + d_xy + r_x)), V the visibility
and A_y/π the disc regularisation of the form factor for nearby patches. A pixel of the range
image covers A = r² cos³α / (f_x f_y cosθ_in) (α: ray angle to the optical axis), so a pixel emits
``(ρ/π) P cos³α / (f_x f_y) · e^{ik r}``: independent of its range and tilt.

Senders are b×b pixel blocks; a block straddling a depth edge or crease is split into at most two
clusters (near the block's closest pixel, and the rest) so no sender floats in mid-air. Visibility
is a screen-space march: points along the segment x→y are projected into the range image and the
path is blocked when a point lies behind the visible surface.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from ..surface import SurfaceImage
from .phasor import SPEED_OF_LIGHT_MM_S
from .rays import ray_directions

#: cosines below this count as zero: grazing pairs carry no light
MIN_COS = 1e-3
#: march points this close (px) to either end's pixel only see that end's own surface
SKIP_PX = 1.5
#: sender tiles span this many blocks per axis
TILE_BLOCKS = 4


@dataclass(frozen=True)
class Senders:
    """Aggregated sender patches.

    Attributes:
        position: (M, 3) float64 mean point in mm (camera frame).
        normal: (M, 3) float64 unit normal facing the camera.
        emission: (M,) complex128 emitted phasor Σ (ρ/π) P cos³α/(fx fy) e^{ik r} (amplitude·mm²).
        area: (M,) float64 surface area in mm².
        tile_start: (T + 1,) int64: senders of tile t are ``tile_start[t]:tile_start[t + 1]``.
        tile_bounds: (T, 9) float64 per tile: centre (3, mm), bounding radius (mm), mean unit
            normal (3), thickness max |n̄·(p − c)| (mm), normal spread max |n − n̄|.
    """

    position: np.ndarray
    normal: np.ndarray
    emission: np.ndarray
    area: np.ndarray
    tile_start: np.ndarray
    tile_bounds: np.ndarray


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


def pixel_emission(surface: SurfaceImage, mod_freq_hz: float, light_power: float) -> np.ndarray:
    """Phasor each sample re-emits into the scene (first bounce), see the module docstring.

    Returns:
        (H, W) complex128 in amplitude·mm²; 0 where no hit or the surface faces away.
    """
    rays = ray_directions(surface.intrinsics)
    facing = -np.einsum("hwk,hwk->hw", surface.normal, rays) > 0
    k = surface.intrinsics
    ok = surface.valid & facing
    r = np.where(ok, surface.range_mm, 0.0)
    mag = np.where(ok, surface.albedo / math.pi * light_power * rays[..., 2] ** 3
                   / (k.fx * k.fy), 0.0)
    return mag * np.exp(1j * (2.0 * math.pi * mod_freq_hz / SPEED_OF_LIGHT_MM_S) * r)


@nb.njit(cache=True)
def _cluster_blocks(points, normals, rng, emission, area, block, tol_rel, tol_mm,
                    cos_tol):  # pragma: no cover - compiled
    h, w = rng.shape
    bh = (h + block - 1) // block
    bw = (w + block - 1) // block
    cap = 2 * bh * bw
    pos = np.zeros((cap, 3))
    nrm = np.zeros((cap, 3))
    emi = np.zeros(cap, dtype=np.complex128)
    are = np.zeros(cap)
    cnt = np.zeros(cap)
    blk = np.zeros(cap, dtype=np.int64)
    m = 0
    for bi in range(bh):
        for bj in range(bw):
            # seed: the block's nearest valid pixel
            si = -1
            sj = -1
            best = np.inf
            for i in range(bi * block, min(h, (bi + 1) * block)):
                for j in range(bj * block, min(w, (bj + 1) * block)):
                    if area[i, j] > 0 and rng[i, j] < best:
                        best = rng[i, j]
                        si = i
                        sj = j
            if si < 0:
                continue
            tol = max(tol_mm, tol_rel * best)
            a_idx = m
            b_idx = m + 1
            blk[a_idx] = bi * bw + bj
            blk[b_idx] = bi * bw + bj
            for i in range(bi * block, min(h, (bi + 1) * block)):
                for j in range(bj * block, min(w, (bj + 1) * block)):
                    if not area[i, j] > 0:
                        continue
                    c = normals[i, j, 0] * normals[si, sj, 0] + normals[i, j, 1] * \
                        normals[si, sj, 1] + normals[i, j, 2] * normals[si, sj, 2]
                    t = a_idx if (rng[i, j] - best < tol and c > cos_tol) else b_idx
                    for q in range(3):
                        pos[t, q] += points[i, j, q]
                        nrm[t, q] += normals[i, j, q]
                    emi[t] += emission[i, j]
                    are[t] += area[i, j]
                    cnt[t] += 1.0
            m += 2
    keep = cnt > 0
    pos = pos[keep]
    nrm = nrm[keep]
    cnt = cnt[keep]
    for t in range(pos.shape[0]):
        n = math.sqrt(nrm[t, 0] ** 2 + nrm[t, 1] ** 2 + nrm[t, 2] ** 2)
        for q in range(3):
            pos[t, q] /= cnt[t]
            nrm[t, q] /= max(n, 1e-12)
    return pos, nrm, emi[keep], are[keep], blk[keep], bw


def _tile_bounds(pos: np.ndarray, nrm: np.ndarray) -> np.ndarray:
    """(9,) bounds of one tile's senders, see :class:`Senders`."""
    centre = pos.mean(axis=0)
    radius = float(np.max(np.linalg.norm(pos - centre, axis=1)))
    mean = nrm.sum(axis=0)
    mean = mean / max(float(np.linalg.norm(mean)), 1e-12)
    thickness = float(np.max(np.abs((pos - centre) @ mean)))
    spread = float(np.max(np.linalg.norm(nrm - mean, axis=1)))
    return np.concatenate([centre, [radius], mean, [thickness, spread]])


def build_senders(surface: SurfaceImage, *, block_px: int, mod_freq_hz: float,
                  light_power: float, tile_blocks: int = TILE_BLOCKS) -> Senders:
    """Aggregate the visible surface into sender patches of ``block_px`` × ``block_px`` pixels.

    Args:
        surface: pixel-resolution surface image.
        block_px: block size in pixels (1 = every pixel is a sender).
        mod_freq_hz: modulation frequency in Hz.
        light_power: P in amplitude·mm².
        tile_blocks: senders are grouped into tiles of this many blocks per axis, whose bounds
            let a receiver skip a whole tile that cannot exchange light with it.
    """
    emission = pixel_emission(surface, mod_freq_hz, light_power)
    area = np.where(np.abs(emission) > 0, np.nan_to_num(pixel_area_mm2(surface)), 0.0)
    points = np.nan_to_num(ray_directions(surface.intrinsics) * surface.range_mm[..., None])
    normals = np.nan_to_num(surface.normal)
    rng = np.where(surface.valid, surface.range_mm, np.inf)
    pos, nrm, emi, are, blk, bw = _cluster_blocks(points, normals, rng, emission, area,
                                                  int(block_px), 0.03, 5.0, 0.8)
    tw = (bw + tile_blocks - 1) // tile_blocks
    tile = (blk // bw) // tile_blocks * tw + (blk % bw) // tile_blocks
    order = np.argsort(tile, kind="stable")
    pos, nrm, emi, are, tile = pos[order], nrm[order], emi[order], are[order], tile[order]
    starts = np.flatnonzero(np.r_[True, tile[1:] != tile[:-1]]) if tile.size else \
        np.zeros(0, np.int64)
    start = np.r_[starts, tile.size].astype(np.int64)
    bounds = np.array([_tile_bounds(pos[a:b], nrm[a:b]) for a, b in itertools.pairwise(start)],
                      dtype=np.float64).reshape(-1, 9)
    return Senders(pos, nrm, emi, are, start, bounds)


@nb.njit(cache=True, inline="always")
def _tile_dark(x0, x1, x2, n0, n1, n2, b, min_cos):  # pragma: no cover - compiled
    """True when no sender of the tile with bounds ``b`` can pass the cosine tests."""
    c0 = b[0] - x0
    c1 = b[1] - x1
    c2 = b[2] - x2
    radius = b[3]
    dist = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    floor = min_cos * max(dist - radius, 0.0)  # lower bound of min_cos · |p − x|
    # receiver side: n_x·(p − x) <= n_x·(c − x) + |n_x·n̄| h + sin∠(n_x, n̄) R
    dot = n0 * b[4] + n1 * b[5] + n2 * b[6]
    sin = math.sqrt(max(0.0, 1.0 - dot * dot))
    if n0 * c0 + n1 * c1 + n2 * c2 + abs(dot) * b[7] + sin * radius <= floor:
        return True
    # sender side: n_y·(x − p) <= n̄·(x − c) + h + spread (|x − c| + R)
    return -(b[4] * c0 + b[5] * c1 + b[6] * c2) + b[7] + b[8] * (dist + radius) <= floor


# fast-math without the no-NaN/no-inf assumptions: holes in the depth image are +inf
@nb.njit(parallel=True, fastmath={"nsz", "arcp", "contract", "afn", "reassoc"}, cache=True)
def _gather(rx_pos, rx_nrm, rx_u, rx_v, s_pos, s_nrm, s_uv, s_emi_re, s_emi_im, s_area,
            tile_start, tile_bounds, depth, fx, fy, cx, cy, k_path, step_px, max_steps, eps_mm,
            eps_rel, min_cos, skip2):  # pragma: no cover - compiled
    n = rx_pos.shape[0]
    n_tiles = tile_bounds.shape[0]
    h, w = depth.shape
    out_re = np.zeros(n)
    out_im = np.zeros(n)
    inv_pi = 1.0 / math.pi
    for i in nb.prange(n):
        x0 = rx_pos[i, 0]
        x1 = rx_pos[i, 1]
        x2 = rx_pos[i, 2]
        n0 = rx_nrm[i, 0]
        n1 = rx_nrm[i, 1]
        n2 = rx_nrm[i, 2]
        ux = rx_u[i]
        vx = rx_v[i]
        acc_re = 0.0
        acc_im = 0.0
        for tt in range(n_tiles):
            if _tile_dark(x0, x1, x2, n0, n1, n2, tile_bounds[tt], min_cos):
                continue
            for j in range(tile_start[tt], tile_start[tt + 1]):
                d0 = s_pos[j, 0] - x0
                d1 = s_pos[j, 1] - x1
                d2 = s_pos[j, 2] - x2
                dd = d0 * d0 + d1 * d1 + d2 * d2
                dist = math.sqrt(dd)
                # (cosines carry a factor dist; below min_cos the pair exchanges no light, which
                # also keeps coplanar pixels of one plane from marching on rounding noise)
                cos_x = n0 * d0 + n1 * d1 + n2 * d2
                if cos_x <= min_cos * dist:
                    continue
                cos_y = -(s_nrm[j, 0] * d0 + s_nrm[j, 1] * d1 + s_nrm[j, 2] * d2)
                if cos_y <= min_cos * dist:
                    continue
                # screen-space visibility march between the receiver and sender pixels
                uy = s_uv[j, 0]
                vy = s_uv[j, 1]
                pix2 = (uy - ux) ** 2 + (vy - vx) ** 2
                steps = min(max_steps, int(math.sqrt(pix2) / step_px))
                visible = True
                for q in range(steps):
                    t = (q + 1.0) / (steps + 1.0)
                    p2 = x2 + t * d2
                    if p2 <= 0.0:
                        continue
                    p0 = x0 + t * d0
                    p1 = x1 + t * d1
                    us = fx * p0 / p2 + cx
                    vs = fy * p1 / p2 + cy
                    # near either end the march only sees the end's own surface
                    near_x = (us - ux) ** 2 + (vs - vx) ** 2 < skip2
                    if near_x or (us - uy) ** 2 + (vs - vy) ** 2 < skip2:
                        continue
                    ui = int(us + 0.5)
                    vi = int(vs + 0.5)
                    if ui < 0 or vi < 0 or ui >= w or vi >= h:
                        continue
                    dz = depth[vi, ui]
                    if not dz < np.inf:
                        continue
                    lim = dz + eps_mm + eps_rel * dz
                    if p0 * p0 + p1 * p1 + p2 * p2 > lim * lim:
                        visible = False
                        break
                if not visible:
                    continue
                g = cos_x * cos_y / (dd * (dd + s_area[j] * inv_pi))
                ph = k_path * dist
                c = math.cos(ph)
                s = math.sin(ph)
                er = s_emi_re[j]
                ei = s_emi_im[j]
                acc_re += g * (er * c - ei * s)
                acc_im += g * (er * s + ei * c)
        out_re[i] = acc_re
        out_im[i] = acc_im
    return out_re, out_im


def indirect_phasor(surface: SurfaceImage, *, mod_freq_hz: float, light_power: float,
                    block_px: int = 3, step_px: float = 3.0, max_steps: int = 8,
                    eps_mm: float = 2.0, eps_rel: float = 0.01,
                    tile_blocks: int = TILE_BLOCKS,
                    receivers: np.ndarray | None = None) -> np.ndarray:
    """One-bounce indirect phasor arriving at every pixel of ``surface``.

    Args:
        surface: pixel-resolution surface image (the visible scene).
        mod_freq_hz: modulation frequency in Hz.
        light_power: P in amplitude·mm².
        block_px: sender block size in pixels.
        step_px: visibility march spacing in pixels.
        max_steps: most visibility samples per receiver–sender pair.
        eps_mm, eps_rel: a march point occludes when it lies more than
            ``eps_mm + eps_rel·range`` behind the visible surface.
        tile_blocks: sender tile size in blocks (tiles that cannot exchange light with a
            receiver are skipped as a whole; the result does not depend on it).
        receivers: (H, W) bool, the pixels whose indirect light is computed (None = all). The
            others still send light but receive none (0): for callers that discard them, e.g.
            the margin of a rendering window. Each receiver's value does not depend on it.

    Returns:
        (H, W) complex128 indirect phasor (same amplitude units as the direct return); 0 where
        the pixel has no hit.
    """
    senders = build_senders(surface, block_px=block_px, mod_freq_hz=mod_freq_hz,
                            light_power=light_power, tile_blocks=tile_blocks)
    h, w = surface.intrinsics.shape
    out = np.zeros((h, w), dtype=np.complex128)
    valid = surface.valid & np.all(np.isfinite(surface.normal), axis=-1)
    if receivers is not None:
        valid &= np.asarray(receivers, dtype=bool)
    if senders.area.size == 0 or not valid.any():
        return out
    vv, uu = np.nonzero(valid)
    k = surface.intrinsics
    depth = np.where(surface.valid, surface.range_mm, np.inf)
    k_path = 2.0 * math.pi * mod_freq_hz / SPEED_OF_LIGHT_MM_S
    s_uv = k.project(senders.position)
    # the d² of the form factor is folded into g = cos_x cos_y / (d² (d² + A/π)) because the
    # cosines above are not normalised (they carry a factor d each)
    points = ray_directions(k) * surface.range_mm[..., None]
    re, im = _gather(points[vv, uu], surface.normal[vv, uu], uu.astype(np.float64),
                     vv.astype(np.float64), senders.position, senders.normal, s_uv,
                     senders.emission.real.copy(), senders.emission.imag.copy(), senders.area,
                     senders.tile_start, senders.tile_bounds, depth, k.fx, k.fy, k.cx, k.cy,
                     k_path, float(step_px), int(max_steps), float(eps_mm), float(eps_rel),
                     MIN_COS, SKIP_PX ** 2)
    r = surface.range_mm[vv, uu]
    out[vv, uu] = surface.albedo[vv, uu] * np.exp(1j * k_path * r) * (re + 1j * im)
    return out
