"""A :class:`SurfaceImage` from a reference range image: the scene as the simulator predicts it.

Normals are local plane fits (PCA) of the back-projected points over a window whose members are
chosen robustly, in two compiled passes. With R = ``smoothing_px`` (default 3):

1. *Every pixel's (2R+1)² window gets a plane.* Its score is the unbiased mean squared residual
   measured **along the rays** (range units). Structured-light noise is range noise: it moves a
   point cos θ off its plane, so a face seen at grazing incidence fits exactly as well as one
   seen head-on, while a plane through a depth edge, which is seen nearly edge-on, scores
   badly. The median score over the image is its *noise floor* σ².
2. *Most pixels stop here*: a full window within ``ACCEPT`` × the floor lies on one plane, and
   that plane is the pixel's (exact for exact planes).
3. *The others* (next to depth edges and creases, on curved faces) score up to 19 more windows,
   all containing the pixel: the window's four halves and four quadrants, the points of the
   window at the pixel's range (``GATE_MM`` + ``GATE_REL`` r: a strip of table seen between
   two objects, narrower than any half) and, for R >= 3, the same at radius R - 1. The score
   adds the pixel's own squared range distance to the plane. Among the windows within
   ``ACCEPT`` × the best score (or the floor), the one with the most points wins: next to an
   edge, a one-sided window lies on the pixel's own surface and fits to the noise, while every
   window across the edge fits worse.
4. *Refit on the inliers.* The winning plane is refitted, twice, on every point of the full
   window within ``INLIER_MM`` + ``INLIER_SIGMAS`` σ of it along its ray, Tukey-weighted. This
   gathers all of the pixel's surface in the window, whatever its shape — the thin strip of a
   box face seen at grazing incidence between its top and the table — and averages the noise
   (0.5 mm at ~1.4 mm pixel spacing tilts plain 3×3 differences by tens of degrees) over up to
   (2R+1)² points.
5. *Creases under noise.* When a window on another plane (more than ``CREASE_DEG`` apart) fits
   within reach too, the pixel's own noisy range cannot tell the planes apart. The other plane
   is refitted on the points off the first; if it still passes through the pixel, the two fits
   decide: a crease is convex when each plane's points lie behind the other plane, and the
   pixel's ray then meets the surface at the farther plane, at the nearer one otherwise.

Why not averaged points and differences (what this module did before): averaging across a
crease bends the surface there, and a face a few pixels wide has no pixel whose window is all
its own, so its normals were 30-70° off. A plane test decides membership by geometry, not by
range, so it separates a crease (same range, different plane) as well as a depth edge.

Left as they are: pixels whose window holds no plane (a lone pixel, a one-pixel-wide line) get
NaN from :func:`normals_from_range`, and :func:`surface_from_reference` turns them to face the
camera. Next to a crease, a pixel either gets its own face's normal or, when the reference
cannot tell the faces apart, the other face's — not a blend of the two, as averaging gave. That
happens most on the rim of a cylinder, whose curved side fits no plane to the noise floor: the
pixels of its last row before the top take the top's normal.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ...camera import Intrinsics
from ...errors import InputError
from ...validation import check_array
from ..surface import SurfaceImage
from .rays import ray_directions

#: albedo assumed when a reference image comes without one
DEFAULT_ALBEDO = 0.5

#: a window scoring within this factor of the best score (or of the floor) may win by size
ACCEPT = 3.0
#: refits keep points within ``INLIER_MM + INLIER_SIGMAS · σ`` of the plane, along their ray
INLIER_MM = 1.0
INLIER_SIGMAS = 3.0
#: refits of the winning plane on its inliers
REFITS = 2
#: a window's plane needs an in-plane spread above this factor × its residual (not a line)
MID_RATIO = 2.0
#: planes seen closer to edge-on than this cosine (0.6°) are not fitted: points along one image
#: line fit such a plane exactly, whatever their noise along the rays
EDGE_ON_COS = 0.01
#: planes further apart than this are told apart at a crease (step 5)
CREASE_DEG = 30.0
_CREASE_COS = math.cos(math.radians(CREASE_DEG))
#: the points of the window within ``GATE_MM + GATE_REL · r`` of the pixel's range r form one
#: more candidate window (a strip of table between two objects, narrower than any half)
GATE_MM = 2.0
GATE_REL = 0.02
#: squared range residual (mm²) below which a fit counts as exact (float64 round-off)
_EXACT_MM2 = 1e-9


def smooth_points(points: np.ndarray, range_mm: np.ndarray, radius: int,
                  tol_rel: float = 0.02, tol_mm: float = 2.0) -> np.ndarray:
    """Edge-aware box average of back-projected points.

    Not used for the normals any more (see the module docstring): averaging across a crease or
    a thin face bends the surface there.

    Args:
        points: (H, W, 3) float64 points in mm, NaN = missing.
        range_mm: (H, W) float64 range in mm, NaN = missing.
        radius: half-width of the (2·radius + 1)² window in pixels (0 = no smoothing).
        tol_rel, tol_mm: neighbours count when their range is within ``tol_mm + tol_rel·r``.

    Returns:
        (H, W, 3) float64 averaged points (NaN where missing).
    """
    if radius <= 0:
        return points
    h, w = range_mm.shape
    pad_r = np.pad(range_mm, radius, constant_values=np.nan)
    pad_p = np.pad(points, ((radius, radius), (radius, radius), (0, 0)),
                   constant_values=np.nan)
    total = np.zeros_like(points)
    count = np.zeros((h, w))
    tol = tol_mm + tol_rel * range_mm
    for dv in range(2 * radius + 1):
        for du in range(2 * radius + 1):
            r_n = pad_r[dv:dv + h, du:du + w]
            same = np.abs(r_n - range_mm) <= tol  # False for NaN on either side
            total += np.where(same[..., None], pad_p[dv:dv + h, du:du + w], 0.0)
            count += same
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count[..., None] > 0, total / count[..., None], np.nan)


# --- compiled kernels ---------------------------------------------------------------------
# Moments m = (Σw, Σwx, Σwy, Σwz, Σwxx, Σwxy, Σwxz, Σwyy, Σwyz, Σwzz) of offsets (x, y, z) from
# the pixel's point, mm. A fit is a row (score, weight, mean offset xyz, unit normal xyz).


@nb.njit(cache=True, error_model="numpy", inline="always")
def _plane(m):  # pragma: no cover - compiled
    """PCA plane of moments m: (ok, residual, mean x, y, z, normal x, y, z).

    residual = the smallest eigenvalue of the covariance (mean squared distance to the plane),
    found as the smallest root of the characteristic cubic by Newton's method from 0 (monotone:
    left of its smallest root the cubic is negative, increasing and concave); the normal is the
    longest cross product of two rows of C - λI. ok = False without a plane: weight below 2.5,
    or an in-plane spread not above ``MID_RATIO`` × the residual.
    """
    n = m[0]
    if n < 2.5:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    mx = m[1] / n
    my = m[2] / n
    mz = m[3] / n
    c00 = m[4] / n - mx * mx
    c01 = m[5] / n - mx * my
    c02 = m[6] / n - mx * mz
    c11 = m[7] / n - my * my
    c12 = m[8] / n - my * mz
    c22 = m[9] / n - mz * mz
    t = c00 + c11 + c22
    if not t > 0.0:
        return False, 0.0, mx, my, mz, 0.0, 0.0, 0.0
    a = c11 * c22 - c12 * c12
    b = c00 * c22 - c02 * c02
    c = c00 * c11 - c01 * c01
    s = a + b + c
    det = c00 * a - c01 * (c01 * c22 - c12 * c02) + c02 * (c01 * c12 - c11 * c02)
    lam = 0.0
    for _ in range(32):
        df = (3.0 * lam - 2.0 * t) * lam + s
        if not df > 0.0:
            break
        step = (((lam - t) * lam + s) * lam - det) / df
        lam -= step
        if abs(step) <= 1e-13 * t:
            break
    lam = max(lam, 0.0)
    rest = t - lam  # the other two eigenvalues: sum rest, product s - λ·rest
    mid = 0.5 * (rest - math.sqrt(max(rest * rest - 4.0 * (s - lam * rest), 0.0)))
    if not (mid > MID_RATIO * lam and mid > 0.0):
        return False, lam, mx, my, mz, 0.0, 0.0, 0.0
    r0x, r0y, r0z = c00 - lam, c01, c02
    r1x, r1y, r1z = c01, c11 - lam, c12
    r2x, r2y, r2z = c02, c12, c22 - lam
    ax, ay, az = r0y * r1z - r0z * r1y, r0z * r1x - r0x * r1z, r0x * r1y - r0y * r1x
    bx, by, bz = r0y * r2z - r0z * r2y, r0z * r2x - r0x * r2z, r0x * r2y - r0y * r2x
    cx, cy, cz = r1y * r2z - r1z * r2y, r1z * r2x - r1x * r2z, r1x * r2y - r1y * r2x
    na = ax * ax + ay * ay + az * az
    nb_ = bx * bx + by * by + bz * bz
    nc = cx * cx + cy * cy + cz * cz
    if nb_ > na and nb_ >= nc:
        ax, ay, az, na = bx, by, bz, nb_
    elif nc > na:
        ax, ay, az, na = cx, cy, cz, nc
    if not na > 0.0:
        return False, lam, mx, my, mz, 0.0, 0.0, 0.0
    k = 1.0 / math.sqrt(na)
    return True, lam, mx, my, mz, ax * k, ay * k, az * k


@nb.njit(cache=True, error_model="numpy", inline="always")
def _cos_incidence(cx, cy, cz, ex, ey, ez):  # pragma: no cover - compiled
    """|cos| of the angle between the unit normal e and the ray to the point c."""
    return abs(ex * cx + ey * cy + ez * cz) / math.sqrt(cx * cx + cy * cy + cz * cz)


@nb.njit(cache=True, error_model="numpy", inline="always")
def _add(m, i, wt, x, y, z):  # pragma: no cover - compiled
    """Add the offset (x, y, z) with weight wt to the moments ``m[i]``."""
    m[i, 0] += wt
    m[i, 1] += wt * x
    m[i, 2] += wt * y
    m[i, 3] += wt * z
    m[i, 4] += wt * x * x
    m[i, 5] += wt * x * y
    m[i, 6] += wt * x * z
    m[i, 7] += wt * y * y
    m[i, 8] += wt * y * z
    m[i, 9] += wt * z * z



@nb.njit(cache=True, inline="always")
def _set_plane(fit, mx, my, mz, ex, ey, ez):  # pragma: no cover - compiled
    """Store a plane (mean point, normal) in slots 2..7 of a fit record."""
    fit[2] = mx
    fit[3] = my
    fit[4] = mz
    fit[5] = ex
    fit[6] = ey
    fit[7] = ez

@nb.njit(cache=True, error_model="numpy")
def _score(m, fit, px, py, pz, own):  # pragma: no cover - compiled
    """Fit the window with moments ``m`` (offsets from the pixel's point p) into ``fit``.

    Score: the unbiased mean squared residual, plus with ``own`` the pixel's squared distance to
    the plane, both along the rays; inf for a window without a plane or seen edge-on.
    """
    n = m[0]
    fit[0] = np.inf
    fit[1] = n
    ok, lam, mx, my, mz, ex, ey, ez = _plane(m)
    if not ok:
        return
    cos = _cos_incidence(px + mx, py + my, pz + mz, ex, ey, ez)
    if cos < EDGE_ON_COS:
        return
    off = (ex * mx + ey * my + ez * mz) if own else 0.0
    fit[0] = (lam * n / max(n - 3.0, 1.0) + off * off) / (cos * cos)
    _set_plane(fit, mx, my, mz, ex, ey, ez)


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _full_windows(points, radius):  # pragma: no cover - compiled
    """(H, W, 8) fit of every pixel's full (2R+1)² window, score without the pixel's own term;
    score NaN for missing pixels."""
    h, w = points.shape[0], points.shape[1]
    out = np.full((h, w, 8), np.nan)
    for vi in nb.prange(h):
        v = np.int64(vi)  # prange indices are unsigned: v - radius must not wrap
        m = np.zeros((1, 10))
        for u in range(w):
            px, py, pz = points[v, u, 0], points[v, u, 1], points[v, u, 2]
            if not (math.isfinite(px) and math.isfinite(py) and math.isfinite(pz)):
                continue
            m[:] = 0.0
            for vv in range(max(v - radius, 0), min(v + radius + 1, h)):
                for uu in range(max(u - radius, 0), min(u + radius + 1, w)):
                    z = points[vv, uu, 2] - pz
                    if math.isfinite(z):
                        _add(m, 0, 1.0, points[vv, uu, 0] - px, points[vv, uu, 1] - py, z)
            _score(m[0], out[v, u], px, py, pz, False)
    return out


@nb.njit(cache=True, error_model="numpy", inline="always")
def _window_sums(blocks, cand):  # pragma: no cover - compiled
    """Moments of the ten candidate windows of one radius, from those of its 3×3 blocks.

    ``blocks`` (10, 10): block 3i + j, i (j) = 0 above (left of) the pixel, 1 its row (column),
    2 below (right); 9 the points at the pixel's range (all blocks). ``cand`` (10, 10): 0 the
    full window, 1-4 halves (up, down, left, right), 5-8 quadrants (up-left, up-right,
    down-left, down-right), 9 the points at the pixel's range. Every window contains the
    pixel.
    """
    for k in range(10):
        r0 = blocks[0, k] + blocks[1, k] + blocks[2, k]
        r1 = blocks[3, k] + blocks[4, k] + blocks[5, k]
        r2 = blocks[6, k] + blocks[7, k] + blocks[8, k]
        c0 = blocks[0, k] + blocks[3, k] + blocks[6, k]
        c1 = blocks[1, k] + blocks[4, k] + blocks[7, k]
        c2 = blocks[2, k] + blocks[5, k] + blocks[8, k]
        centre = blocks[4, k]
        cand[0, k] = r0 + r1 + r2
        cand[1, k] = r0 + r1
        cand[2, k] = r1 + r2
        cand[3, k] = c0 + c1
        cand[4, k] = c1 + c2
        cand[5, k] = blocks[0, k] + blocks[1, k] + blocks[3, k] + centre
        cand[6, k] = blocks[1, k] + blocks[2, k] + centre + blocks[5, k]
        cand[7, k] = blocks[3, k] + centre + blocks[6, k] + blocks[7, k]
        cand[8, k] = centre + blocks[5, k] + blocks[7, k] + blocks[8, k]
        cand[9, k] = blocks[9, k]


@nb.njit(cache=True, error_model="numpy")
def _largest_within(fits, n, reach, other):  # pragma: no cover - compiled
    """Index of the fit with the most points (then the best score) among ``fits[:n]`` scoring
    within ``reach``; with ``other`` >= 0 only fits more than ``CREASE_DEG`` from the plane of
    ``fits[other]``. -1 if none."""
    pick = -1
    for i in range(n):
        if not fits[i, 0] <= reach:
            continue
        if other >= 0 and abs(fits[i, 5] * fits[other, 5] + fits[i, 6] * fits[other, 6]
                               + fits[i, 7] * fits[other, 7]) >= _CREASE_COS:
            continue
        if pick < 0 or fits[i, 1] > fits[pick, 1] or (fits[i, 1] == fits[pick, 1]
                                                       and fits[i, 0] < fits[pick, 0]):
            pick = i
    return pick


@nb.njit(cache=True, error_model="numpy")
def _other_plane_wins(a, b, px, py, pz):  # pragma: no cover - compiled
    """Whether the ray through p meets the surface on the plane of fit b rather than fit a.

    With the normals turned towards the camera, the crease is convex when each plane's points
    lie behind the other plane; the ray then meets the surface at the farther plane (it enters
    the solid through both), and at the nearer one otherwise.
    """
    na = a[5] * (px + a[2]) + a[6] * (py + a[3]) + a[7] * (pz + a[4])  # n·c, c = p + mean
    nb_ = b[5] * (px + b[2]) + b[6] * (py + b[3]) + b[7] * (pz + b[4])
    sa = -1.0 if na > 0.0 else 1.0  # turns the normal towards the camera (n·c < 0)
    sb = -1.0 if nb_ > 0.0 else 1.0
    behind = (sa * (a[5] * (b[2] - a[2]) + a[6] * (b[3] - a[3]) + a[7] * (b[4] - a[4]))
              + sb * (b[5] * (a[2] - b[2]) + b[6] * (a[3] - b[3]) + b[7] * (a[4] - b[4])))
    da = a[5] * px + a[6] * py + a[7] * pz
    db = b[5] * px + b[6] * py + b[7] * pz
    if da == 0.0 or db == 0.0:
        return False
    ta = na / da  # the ray s·p meets the plane at s = n·c / n·p
    tb = nb_ / db
    return tb > ta if behind < 0.0 else tb < ta


@nb.njit(cache=True, error_model="numpy")
def _refit(points, rays, v, u, radius, tol, fit, other, exclude, refits,
           m):  # pragma: no cover - compiled
    """Refit ``fit`` ``refits`` times on the points of the window within ``tol`` of its plane
    along their rays, Tukey-weighted by that distance; with ``exclude``, leaving out the points
    within ``tol`` of the plane of ``other``. Keeps the last plane that fitted, with its weight
    in ``fit[1]``; returns whether the first refit fitted."""
    h, w = points.shape[0], points.shape[1]
    px, py, pz = points[v, u, 0], points[v, u, 1], points[v, u, 2]
    for it in range(refits):
        mx, my, mz, ex, ey, ez = fit[2], fit[3], fit[4], fit[5], fit[6], fit[7]
        m[:] = 0.0
        for vv in range(max(v - radius, 0), min(v + radius + 1, h)):
            for uu in range(max(u - radius, 0), min(u + radius + 1, w)):
                x = points[vv, uu, 0] - px
                y = points[vv, uu, 1] - py
                z = points[vv, uu, 2] - pz
                rx, ry, rz = rays[vv, uu, 0], rays[vv, uu, 1], rays[vv, uu, 2]
                band = tol * abs(ex * rx + ey * ry + ez * rz)
                d = ex * (x - mx) + ey * (y - my) + ez * (z - mz)
                if not abs(d) < band:  # also drops missing points (NaN)
                    continue
                if exclude and abs(other[5] * (x - other[2]) + other[6] * (y - other[3])
                                   + other[7] * (z - other[4])) < tol * abs(
                                       other[5] * rx + other[6] * ry + other[7] * rz):
                    continue
                t = d / band
                _add(m, 0, (1.0 - t * t) ** 2, x, y, z)
        ok, _, mx, my, mz, ex, ey, ez = _plane(m[0])
        if not ok or _cos_incidence(px + mx, py + my, pz + mz, ex, ey, ez) < EDGE_ON_COS:
            return it > 0
        fit[1] = m[0, 0]
        _set_plane(fit, mx, my, mz, ex, ey, ez)
    return True


@nb.njit(cache=True, error_model="numpy")
def _edge_normal(points, rays, range_mm, full, v, u, radius, noise2, tol, blocks, cand, fits,
                 m):  # pragma: no cover - compiled
    """Steps 3-5 of the module docstring for pixel (v, u), whose full window ``full`` (a fit)
    is not within reach of the noise floor. Returns its unit normal (sign not oriented), or
    (0, 0, 0) when no window holds a plane. ``blocks``, ``cand`` (2, 10, 10), ``fits``
    (20, 8), ``m`` (1, 10): scratch."""
    h, w = points.shape[0], points.shape[1]
    px, py, pz = points[v, u, 0], points[v, u, 1], points[v, u, 2]
    scales = 2 if radius >= 3 else 1  # radius R, and R - 1
    r0 = range_mm[v, u]
    gate = GATE_MM + GATE_REL * r0
    blocks[:] = 0.0
    for dv in range(max(-radius, -v), min(radius, h - 1 - v) + 1):
        bi = 0 if dv < 0 else (3 if dv == 0 else 6)
        for du in range(max(-radius, -u), min(radius, w - 1 - u) + 1):
            z = points[v + dv, u + du, 2] - pz
            if not math.isfinite(z):
                continue
            x = points[v + dv, u + du, 0] - px
            y = points[v + dv, u + du, 1] - py
            b = bi + (0 if du < 0 else (1 if du == 0 else 2))
            near = abs(range_mm[v + dv, u + du] - r0) < gate
            _add(blocks[0], b, 1.0, x, y, z)
            if near:
                _add(blocks[0], 9, 1.0, x, y, z)
            if scales == 2 and abs(dv) < radius and abs(du) < radius:
                _add(blocks[1], b, 1.0, x, y, z)
                if near:
                    _add(blocks[1], 9, 1.0, x, y, z)
    best = np.inf
    for s in range(scales):
        _window_sums(blocks[s], cand[s])
        min_points = (radius - s + 1) ** 2 // 2 + 1  # a one-sided window at least half full
        for c in range(10):
            i = 10 * s + c
            fits[i, 0] = np.inf
            fits[i, 1] = cand[s, c, 0]
            if c == 0 or cand[s, c, 0] >= min_points:
                _score(cand[s, c], fits[i], px, py, pz, True)
                best = min(best, fits[i, 0])
    if best == np.inf:
        return 0.0, 0.0, 0.0
    reach = ACCEPT * max(best, noise2) + _EXACT_MM2
    pick = _largest_within(fits, 10 * scales, reach, -1)
    alt = _largest_within(fits, 10 * scales, reach, pick)
    _refit(points, rays, v, u, radius, tol, fits[pick], fits[pick], False, REFITS, m)
    if alt >= 0:
        a, b = fits[pick], fits[alt]
        refitted = _refit(points, rays, v, u, radius, tol, b, a, True, REFITS, m)
        off = abs(b[5] * b[2] + b[6] * b[3] + b[7] * b[4])  # the pixel's distance to plane b
        if (refitted and b[1] >= (radius - scales + 2) ** 2 // 2 + 1
                and off < tol * _cos_incidence(px, py, pz, b[5], b[6], b[7])
                and abs(a[5] * b[5] + a[6] * b[6] + a[7] * b[7]) < _CREASE_COS
                and _other_plane_wins(a, b, px, py, pz)):
            pick = alt
    return fits[pick, 5], fits[pick, 6], fits[pick, 7]


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _plane_normals(points, rays, range_mm, full, radius, noise2):  # pragma: no cover - compiled
    """(H, W, 3) unit normals (sign not oriented) of (H, W, 3) points (NaN = missing) seen along
    (H, W, 3) unit rays, given their full-window fits ``full`` and the noise floor ``noise2``
    (mm², squared range residual); NaN where no window holds a plane."""
    h, w = points.shape[0], points.shape[1]
    out = np.full((h, w, 3), np.nan)
    floor = ACCEPT * noise2 + _EXACT_MM2
    tol = INLIER_MM + INLIER_SIGMAS * math.sqrt(noise2)
    for vi in nb.prange(h):
        v = np.int64(vi)  # prange indices are unsigned: v - radius must not wrap
        blocks = np.zeros((2, 10, 10))
        cand = np.zeros((2, 10, 10))
        fits = np.zeros((20, 8))
        m = np.zeros((1, 10))
        for u in range(w):
            score = full[v, u, 0]
            if math.isnan(score):
                continue
            if score <= floor:
                ex, ey, ez = full[v, u, 5], full[v, u, 6], full[v, u, 7]
            else:
                ex, ey, ez = _edge_normal(points, rays, range_mm, full[v, u], v, u, radius,
                                          noise2, tol, blocks, cand, fits, m)
                if ex == 0.0 and ey == 0.0 and ez == 0.0:
                    continue
            out[v, u, 0] = ex
            out[v, u, 1] = ey
            out[v, u, 2] = ez
    return out


def normals_from_range(range_mm: np.ndarray, intrinsics: Intrinsics,
                       smoothing_px: int = 3) -> np.ndarray:
    """Unit surface normals of a radial range image, oriented towards the camera.

    Robust local plane fits, see the module docstring.

    Args:
        range_mm: (H, W) float radial range in mm, NaN = missing.
        intrinsics: intrinsics of the image.
        smoothing_px: half-width R >= 1 of the (2R+1)² plane-fit window in pixels (R >= 3 also
            tries windows of radius R - 1 next to edges).

    Returns:
        (H, W, 3) float64 unit normals in the camera frame; NaN where the range is missing or
        no window around the pixel holds a plane (a lone pixel, a one-pixel-wide line).

    Raises:
        InputError: ``smoothing_px`` below 1.
    """
    radius = int(smoothing_px)
    if radius < 1:
        raise InputError(f"smoothing_px: expected an integer >= 1, got {smoothing_px!r}")
    r = np.asarray(range_mm, dtype=np.float64)
    rays = ray_directions(intrinsics)
    points = np.ascontiguousarray(rays * r[..., None])
    full = _full_windows(points, radius)
    scores = full[..., 0][np.isfinite(full[..., 0])]
    noise2 = float(np.median(scores)) if scores.size else 0.0
    n = _plane_normals(points, rays, r, full, radius, noise2)
    # face the camera: dot(n, ray) <= 0
    flip = np.einsum("hwk,hwk->hw", n, rays) > 0
    n[flip] *= -1.0
    n[~np.isfinite(r)] = np.nan
    return n


def surface_from_reference(reference_range_mm: np.ndarray, intrinsics: Intrinsics,
                           albedo: np.ndarray | float | None = None,
                           material_id: np.ndarray | None = None, *,
                           smoothing_px: int = 3) -> SurfaceImage:
    """The visible surface described by a reference range image.

    Args:
        reference_range_mm: (H, W) float radial range in mm, NaN = missing (stays a hole).
        intrinsics: intrinsics of the H x W image.
        albedo: (H, W) float albedo in [0, 1], a scalar, or None for ``DEFAULT_ALBEDO``.
        material_id: (H, W) int material index, or None for material 0 everywhere.
        smoothing_px: half-width (px, >= 1) of the plane-fit window of the normals, see
            :func:`normals_from_range`.

    Returns:
        SurfaceImage on the same grid (missing pixels stay holes; pixels with no plane around
        them to take a normal from — a lone pixel, a one-pixel-wide line — face the camera).

    Raises:
        InputError: wrong shapes, non-positive ranges, albedo outside [0, 1] or
            ``smoothing_px`` below 1.
    """
    r = check_array("reference_range_mm", reference_range_mm, ndim=2, shape=intrinsics.shape,
                    dtype_kind="fiu").astype(np.float64)
    r = np.where(np.isfinite(r), r, np.nan)
    if np.any(r <= 0):
        raise InputError("reference_range_mm: ranges must be > 0 mm (use NaN for missing)")
    if albedo is None:
        albedo = DEFAULT_ALBEDO
    rho = np.broadcast_to(np.asarray(albedo, dtype=np.float64), r.shape)
    rho = check_array("albedo", rho, shape=intrinsics.shape, dtype_kind="fiu")
    if not np.all((rho >= 0) & (rho <= 1)):
        raise InputError("albedo: expected finite values in [0, 1]")
    normal = normals_from_range(r, intrinsics, smoothing_px)
    # pixels without a plane around them are taken to face the camera
    lone = np.isfinite(r) & ~np.all(np.isfinite(normal), axis=-1)
    normal[lone] = -ray_directions(intrinsics)[lone]
    hit = np.isfinite(r)
    mat = np.zeros(r.shape, np.int32) if material_id is None else np.asarray(material_id)
    return SurfaceImage(range_mm=r, normal=normal, albedo=np.where(hit, rho, 0.0),
                        object_id=np.where(hit, 0, -1).astype(np.int32),
                        material_id=np.where(hit, mat, -1).astype(np.int32),
                        intrinsics=intrinsics)
