"""Range-image edges: ground-truth boundaries, the boundary networks' edge map, Canny baseline.

Conventions shared by every function here (and by the boundary networks G, which are trained on
the orientation groups of :func:`ground_truth_edges`):

* image axes: ``x`` = column (right), ``y`` = row (down);
* an edge's *normal* is the range-gradient direction, measured from +x towards +y, modulo 180°;
* orientation group ``g`` in 0..3 holds normals nearest ``45° * g``: 0 = horizontal normal
  (a vertical edge line), 1 = normal along (+x, +y), 2 = vertical normal (a horizontal line),
  3 = normal along (-x, +y); -1 = not an edge. :data:`GROUP_NORMALS` gives each group's unit
  pixel step ``(dy, dx)`` along the normal, used by non-maximum suppression.

Edge strength of a range image is the *step height*: ``|Sobel| / 4`` (Sobel 3x3), i.e. the range
difference in mm between the pixels on either side of a pixel (smoothed across). A clean depth
step of D mm gives D; a tilted plane whose range changes by s mm per pixel gives 2 s.

Non-maximum suppression and hysteresis are written here (vectorised numpy plus OpenCV connected
components) rather than taken from ``cv2.Canny``, which derives its directions from its own
int16 Sobel gradients of an 8-bit image: the networks give a direction as a group index, the
ground truth needs float thresholds in mm and a foreground tie-break, and both must share one
definition of "maximum". The baseline :func:`canny_edges` *is* ``cv2.Canny``, as the paper
compares against the stock detector.
"""

from __future__ import annotations

import math

import cv2
import numba
import numpy as np
from scipy import ndimage

from ..errors import InputError
from ..validation import check_array

# (dy, dx) unit pixel step along the normal of each orientation group (0°, 45°, 90°, 135°).
GROUP_NORMALS: np.ndarray = np.array([[0, 1], [1, 1], [1, 0], [1, -1]], dtype=np.int64)

# Default thresholds of ground_truth_edges / canny_edges, in mm of step height (|Sobel| / 4).
# Objects of 100-200 mm on a table seen from 180-450 mm: an occluding step of >= 20 mm is a
# strong edge, steps of 10-20 mm survive when connected to one. A tilted plane reads 2 s where
# s = R tan(incidence) / f mm per pixel (f ~ 212 px for the DS325): the table at 450 mm stays
# below the 10 mm low threshold up to ~67° incidence, so planes do not fire.
GT_LOW_MM = 10.0
GT_HIGH_MM = 20.0


def _check_thresholds(low: float, high: float) -> None:
    if not (np.isfinite(low) and np.isfinite(high) and 0.0 <= low <= high):
        raise InputError(f"thresholds: expected finite 0 <= low <= high, got low={low}, "
                         f"high={high}")


def fill_missing(range_mm: np.ndarray, valid: np.ndarray, *, step_mm: float = 2 * GT_HIGH_MM,
                 radius_px: int = 3) -> np.ndarray:
    """Fill missing pixels from their neighbours without inventing depth steps at hole rims.

    Each missing pixel takes the value of its nearest valid pixel, which continues every rim
    almost flat: a hole inside a surface or at the image border adds no edge. One exception puts
    real steps back: missing pixels lie mostly in structured-light occlusion shadows, on the
    *background* side of a depth step. Where the farthest valid range within ``radius_px``
    exceeds the nearest-pixel value by more than ``step_mm``, the pixel takes that farther value,
    so a shadow up to ``radius_px`` wide is filled with background and the step stays on the
    valid foreground silhouette. The farthest pixel can be ``radius_px`` plus the distance to
    the nearest one away, so a tilted plane triggers this only above about
    ``step_mm / (2 radius_px)`` mm per pixel (40 mm / 6 px ~ 6.7 mm/px by default, steeper than
    the table is at 180-450 mm); wider shadows and smaller hidden steps keep nearest-pixel
    filling, and the step hidden in them is not reported.

    Args:
        range_mm: (H, W) float radial range in mm; values at ``~valid`` are ignored.
        valid: (H, W) bool, True where ``range_mm`` is a measurement.
        step_mm: smallest range difference treated as a hidden depth step, mm.
        radius_px: how far across a hole the background is looked for, pixels.

    Returns:
        (H, W) float32 range in mm, finite everywhere (all zeros if nothing is valid).
    """
    if not valid.any():
        return np.zeros(range_mm.shape, np.float32)
    known = np.where(valid, range_mm, -np.inf).astype(np.float32)
    if valid.all():
        return known
    nearest_idx = ndimage.distance_transform_edt(~valid, return_distances=False,
                                                 return_indices=True)
    nearest = known[tuple(nearest_idx)]
    size = 2 * radius_px + 1
    farthest = cv2.dilate(known, np.ones((size, size), np.uint8),
                          borderType=cv2.BORDER_CONSTANT, borderValue=-np.inf)
    hidden_step = ~valid & (farthest - nearest > step_mm)
    return np.where(hidden_step, farthest, nearest).astype(np.float32)


def _step_gradients(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sobel 3x3 gradients scaled to step height (mm): a step of D mm reads D.

    Returns:
        gx, gy: (H, W) float32, mm; border pixels replicate their neighbours.
    """
    gx = cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=3, scale=0.25, borderType=cv2.BORDER_REPLICATE)
    gy = cv2.Sobel(image, cv2.CV_32F, 0, 1, ksize=3, scale=0.25, borderType=cv2.BORDER_REPLICATE)
    return gx, gy


def orientation_group(gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """Quantise gradient directions (normals, modulo 180°) into the 4 groups.

    Args:
        gx, gy: (H, W) float gradient components along x (columns) and y (rows).

    Returns:
        (H, W) int8 group in 0..3 (nearest of 0°, 45°, 90°, 135°).
    """
    angle = np.degrees(np.arctan2(gy, gx)) % 180.0
    return (np.floor(angle / 45.0 + 0.5).astype(np.int64) % 4).astype(np.int8)


def non_maximum_suppression(strength: np.ndarray, group: np.ndarray,
                            tiebreak: np.ndarray | None = None) -> np.ndarray:
    """Keep pixels whose strength is a local maximum along their group's normal.

    A ridge whose crest falls between two pixels has two equal maxima; exactly one is kept: the
    one with the lower ``tiebreak`` value (the foreground pixel when ``tiebreak`` is range),
    else the one earlier along the normal (``> previous`` and ``>= next``).

    Args:
        strength: (H, W) float edge strength (any unit); outside the image counts as 0.
        group: (H, W) integer orientation group 0..3 of each pixel (other values: suppressed).
        tiebreak: optional (H, W) float; on equal strength the lower value wins.

    Returns:
        (H, W) bool, True at local maxima with strength > 0.
    """
    h, w = strength.shape
    s = strength.astype(np.float32, copy=False)
    key = np.zeros((h, w), np.float32) if tiebreak is None else tiebreak.astype(np.float32)
    s_pad, k_pad = np.pad(s, 1), np.pad(key, 1, mode="edge")
    keep = np.zeros((h, w), bool)
    for g, (dy, dx) in enumerate(GROUP_NORMALS):
        nxt = (slice(1 + dy, 1 + dy + h), slice(1 + dx, 1 + dx + w))
        prv = (slice(1 - dy, 1 - dy + h), slice(1 - dx, 1 - dx + w))
        beats_prev = (s > s_pad[prv]) | ((s == s_pad[prv]) & (key < k_pad[prv]))
        beats_next = (s > s_pad[nxt]) | ((s == s_pad[nxt]) & (key <= k_pad[nxt]))
        keep |= (group == g) & beats_prev & beats_next
    return keep & (s > 0)


def _step_corners(edges: np.ndarray, side: int) -> np.ndarray:
    """Pixels with an edge neighbour at ``side`` (-1 left, +1 right) and below, whose other edge
    neighbours all touch one of those two arms (so removing the pixel disconnects nothing)."""
    h, w = edges.shape
    p = np.pad(edges, 1)

    def at(dy: int, dx: int) -> np.ndarray:
        return p[1 + dy:1 + dy + h, 1 + dx:1 + dx + w]

    # Up, the opposite side and the opposite upper diagonal touch neither arm.
    forbidden = at(-1, 0) | at(0, -side) | at(-1, -side)
    return edges & at(0, side) & at(1, 0) & ~forbidden


def thin_staircases(edges: np.ndarray) -> np.ndarray:
    """Drop the redundant corner pixels of 4-connected staircases, keeping 8-connectivity.

    Non-maximum suppression along a diagonal normal compares pixels two diagonals apart, so a
    diagonal ridge survives on both pixel diagonals nearest its crest: a 4-connected staircase,
    two pixels per row. A step corner has one arm beside it and one below, and those two touch
    diagonally; when every other edge neighbour of the corner touches an arm too, removing it
    keeps every 8-connected component intact (and the line still a barrier for
    :mod:`tof_mpd_ros.correction.geodesic`). Corners with a left arm and with a right arm are
    removed in two vectorised passes; within one pass no arm is itself a corner, so
    simultaneous removals are safe.

    Args:
        edges: (H, W) bool edge map.

    Returns:
        (H, W) bool thinned edge map.
    """
    edges = edges & ~_step_corners(edges, -1)
    return edges & ~_step_corners(edges, +1)


def hysteresis(candidates: np.ndarray, strength: np.ndarray, low: float,
               high: float) -> np.ndarray:
    """Canny hysteresis: keep 8-connected runs of ``strength >= low`` that touch ``>= high``.

    Args:
        candidates: (H, W) bool, pixels allowed to be edges (after non-maximum suppression).
        strength: (H, W) float edge strength, same unit as the thresholds.
        low, high: thresholds, ``low <= high``.

    Returns:
        (H, W) bool edge map.
    """
    weak = candidates & (strength >= low)
    n, labels = cv2.connectedComponents(weak.astype(np.uint8), connectivity=8)
    seeded = np.zeros(n, bool)
    seeded[labels[weak & (strength >= high)]] = True
    seeded[0] = False  # label 0 is the background
    return seeded[labels]


def ground_truth_edges(reference_mm: np.ndarray, *, low: float = GT_LOW_MM,
                       high: float = GT_HIGH_MM) -> tuple[np.ndarray, np.ndarray]:
    """Canny edges of a reference range image and their orientation groups (the paper's labels).

    Missing pixels are filled by :func:`fill_missing` and their gradient is then zeroed, so
    (a) no edge pixel is ever a missing pixel, (b) the rim of a hole inside a surface or at the
    image border does not fire (the fill continues the rim), and (c) a real depth step hidden
    behind a narrow occlusion shadow is still found, on the valid foreground pixel of the
    silhouette. Where a step's two sides tie in non-maximum suppression the nearer (foreground)
    pixel is the edge, so edges sit on object silhouettes. As with any Canny, a step running
    exactly diagonally comes out as a 4-connected staircase (both pixel diagonals next to it);
    it is left so, since thinning would drop foreground pixels as often as background ones.

    Args:
        reference_mm: (H, W) float radial range in mm, NaN = missing.
        low, high: hysteresis thresholds in mm of step height (|Sobel| / 4, see the module doc).

    Returns:
        edge_mask: (H, W) bool.
        orientation_group: (H, W) int8, 0..3 on edges (see :data:`GROUP_NORMALS`), -1 elsewhere.
    """
    ref = check_array("reference_mm", reference_mm, ndim=2, dtype_kind="fiu")
    _check_thresholds(low, high)
    valid = np.isfinite(ref)
    filled = fill_missing(ref, valid, step_mm=2.0 * high)
    gx, gy = _step_gradients(filled)
    gx[~valid] = 0.0
    gy[~valid] = 0.0
    strength = np.hypot(gx, gy)
    group = orientation_group(gx, gy)
    maxima = non_maximum_suppression(strength, group, tiebreak=filled)
    edges = hysteresis(maxima, strength, low, high)
    return edges, np.where(edges, group, -1).astype(np.int8)


def edge_map_from_responses(scores: np.ndarray, *, low: float = 0.3,
                            high: float = 0.6) -> tuple[np.ndarray, np.ndarray]:
    """Binary edge map from the four orientation networks' edge probabilities (paper §3.2).

    Per pixel the maximum over the 4 groups gives the score and the direction; non-maximum
    suppression along the winning group's normal, then :func:`thin_staircases`, thin ridges to
    one pixel (8-connected lines); hysteresis keeps weak maxima (>= ``low``) only when
    8-connected to a strong one (>= ``high``).

    Args:
        scores: (4, H, W) float edge probabilities in [0, 1], one map per orientation group.
        low, high: hysteresis thresholds on the probability.

    Returns:
        edges: (H, W) bool edge map.
        strength: (H, W) float32, the max score where it survives non-maximum suppression and
            0 elsewhere (threshold it for precision/recall sweeps without hysteresis).
    """
    s = check_array("scores", scores, ndim=3, shape=(4, None, None), dtype_kind="fiu")
    _check_thresholds(low, high)
    s = np.nan_to_num(s.astype(np.float32, copy=False), nan=0.0, posinf=1.0, neginf=0.0)
    return edge_map_from_best(np.max(s, axis=0), np.argmax(s, axis=0), low=low, high=high)


def edge_map_from_best(best: np.ndarray, group: np.ndarray, *, low: float = 0.3,
                       high: float = 0.6) -> tuple[np.ndarray, np.ndarray]:
    """:func:`edge_map_from_responses` from the per-pixel maximum and its group.

    The fast path computes the maximum over the four heads (and the first head reaching it)
    inside its network kernel and enters here, skipping the (4, H, W) score stack.

    Args:
        best: (H, W) float32 maximum edge probability over the groups, finite.
        group: (H, W) integer group 0..3 of that maximum (the first one on ties).
        low, high: hysteresis thresholds on the probability.

    Returns:
        edges, strength: as :func:`edge_map_from_responses`.
    """
    _check_thresholds(low, high)
    maxima = thin_staircases(non_maximum_suppression(best, group))
    edges = hysteresis(maxima, best, low, high)
    return edges, np.where(maxima, best, 0.0).astype(np.float32)


def unsure_edge_decisions(logit: np.ndarray, margin: np.ndarray, group: np.ndarray,
                          valid: np.ndarray, error: float, pair_error: float, *,
                          low: float = 0.3, high: float = 0.6) -> np.ndarray:
    """Pixels whose part in :func:`edge_map_from_best` may change if every logit is off by up
    to ``error`` and two logits' errors differ by up to ``pair_error``: where a
    reduced-precision G must be recomputed in float32 to give float32's edges.

    A head's probability is the float32 rounding of ``sigmoid(logit)``, increasing in the logit,
    so a pixel's float32 probability lies in ``[sigmoid(logit - error), sigmoid(logit + error)]``
    (both rounded), and two logits more than ``pair_error`` apart keep their order. Only a pixel
    that can reach ``low`` and whose 8-connected run of such pixels can reach ``high`` can be an
    edge (a candidate). A candidate that is certainly not a local maximum (a neighbour along
    each normal it may have is certainly larger) decides nothing of its own; at the others a
    decision is unsure where

    * its interval contains ``low`` or ``high`` (hysteresis),
    * its runner-up head is within ``pair_error`` (the group, which picks the NMS neighbours),
    * a neighbour it is compared with in non-maximum suppression is within ``pair_error``, or
      both are so close to 1 that float32 may round them equal (logits above
      :data:`_ROUNDS_TOGETHER`) — then both are unsure; a candidate with an unsure group is
      compared along all four normals.

    Recomputing the unsure pixels makes every decision at candidate pixels float32's. Not
    covered: the staircase thinning also reads maxima up to 2 px from a candidate (measured on
    MD-Test in int8: 4 edge pixels of 45 frames differ, docs/performance.md).

    Args:
        logit: (H, W) float32 best head's logit difference (``HeadOutputs.logit``).
        margin: (H, W) float32 its lead over the runner-up head (>= 0).
        group: (H, W) integer group 0..3 of the best head.
        valid: (H, W) bool pixels with a measurement (others have probability 0, certain).
        error: the largest error of one logit assumed (>= 0).
        pair_error: the largest difference assumed between the errors of two logits (two
            pixels', or two heads' of one pixel); at most ``2 error``.
        low, high: the hysteresis thresholds on the probability.

    Returns:
        (H, W) bool, True where the pixel must be recomputed.
    """
    _check_thresholds(low, high)
    if not (error >= 0 and 0 <= pair_error <= 2 * error):
        raise InputError(f"need error >= 0 and 0 <= pair_error <= 2 error, got {error}, "
                         f"{pair_error}")
    logit = np.ascontiguousarray(logit, np.float32)
    valid = np.ascontiguousarray(valid, bool)
    can_be_weak = np.zeros(logit.shape, np.uint8)
    can_be_strong = np.zeros(logit.shape, bool)
    # the sigmoid is evaluated only above (a little below) the low threshold's logit
    near = math.log(low / (1.0 - low)) - 0.01 if 0.0 < low < 1.0 else -math.inf
    _reachable(logit, valid, float(error), near, np.float32(low), np.float32(high),
               can_be_weak, can_be_strong)
    if not can_be_strong.any():                    # no edge can start anywhere
        return np.zeros(logit.shape, bool)
    n, labels = cv2.connectedComponents(can_be_weak, connectivity=8)
    seeded = np.zeros(n, bool)
    seeded[labels[can_be_strong]] = True
    seeded[0] = False
    unsure = np.zeros(logit.shape, bool)
    lo = np.empty(logit.shape, np.float32)
    hi = np.empty(logit.shape, np.float32)
    _unsure_kernel(seeded[labels], logit, valid, np.ascontiguousarray(margin, np.float32),
                   np.ascontiguousarray(group, np.int64), float(error), float(pair_error),
                   np.float32(low), np.float32(high), GROUP_NORMALS,
                   np.zeros(logit.shape, bool), lo, hi, unsure)
    return unsure


# Logits above this may round to equal float32 probabilities though more than a pair error
# apart: near 1 one float32 step (6e-8) spans 6e-8 / (1 - p) in logit, 0.2 at 15.2 (so ties
# there are treated as possible); below 14 a step spans under 0.02.
_ROUNDS_TOGETHER = 14.0


@numba.njit(cache=True, nogil=True, inline="always")
def _rounded_sigmoid(x: float) -> np.float32:  # pragma: no cover
    """float32 of sigmoid(x) evaluated in float64, as the network kernels round it."""
    return np.float32(1.0 / (1.0 + math.exp(-x)))


@numba.njit(cache=True, nogil=True)
def _reachable(logit: np.ndarray, valid: np.ndarray, error: float, near: float,
               low: np.float32, high: np.float32, can_be_weak: np.ndarray,
               can_be_strong: np.ndarray) -> None:  # pragma: no cover
    """Valid pixels whose float32 probability can reach ``low`` / ``high``; the sigmoid is
    evaluated only where the logit plus ``error`` exceeds ``near`` (most pixels are far
    below the threshold)."""
    h, w = logit.shape
    for y in range(h):
        for x in range(w):
            top = logit[y, x] + error
            if valid[y, x] and top > near:
                p = _rounded_sigmoid(top)
                can_be_weak[y, x] = p >= low
                can_be_strong[y, x] = p >= high


@numba.njit(cache=True, nogil=True)
def _unsure_kernel(candidate: np.ndarray, logit: np.ndarray, valid: np.ndarray,
                   margin: np.ndarray, group: np.ndarray, error: float, pair_error: float,
                   low: np.float32, high: np.float32, normals: np.ndarray, known: np.ndarray,
                   lo: np.ndarray, hi: np.ndarray, unsure: np.ndarray) -> None:  # pragma: no cover
    """:func:`unsure_edge_decisions`' rules at the candidate pixels, marking ``unsure``; the
    probability interval of a pixel is computed the first time it is needed (``known``)."""
    h, w = logit.shape
    for y in range(h):
        for x in range(w):
            if not candidate[y, x]:
                continue
            any_group = margin[y, x] <= pair_error
            if _certainly_suppressed(logit, y, x, group[y, x], any_group, error, pair_error,
                                     normals):
                continue
            _interval(logit, valid, error, y, x, known, lo, hi)
            a, b = lo[y, x], hi[y, x]
            if (a < low <= b) or (a < high <= b) or any_group:
                unsure[y, x] = True
            lp = np.float64(logit[y, x])
            for g in range(4):
                if not any_group and g != group[y, x]:
                    continue
                for sign in (-1, 1):
                    yy, xx = y + sign * normals[g, 0], x + sign * normals[g, 1]
                    if yy < 0 or yy >= h or xx < 0 or xx >= w or not valid[yy, xx]:
                        continue            # outside or invalid counts as 0: below p
                    lq = np.float64(logit[yy, xx])
                    if abs(lp - lq) <= pair_error or min(lp, lq) > _ROUNDS_TOGETHER - error:
                        _interval(logit, valid, error, yy, xx, known, lo, hi)
                        c, d = lo[yy, xx], hi[yy, xx]
                        if a <= d and c <= b and not (a == b and c == d):
                            unsure[y, x] = True
                            unsure[yy, xx] = True


@numba.njit(cache=True, nogil=True, inline="always")
def _certainly_suppressed(logit: np.ndarray, y: int, x: int, own: int, any_group: bool,
                          error: float, pair_error: float,
                          normals: np.ndarray) -> bool:  # pragma: no cover
    """Whether along every normal pixel (y, x) may take (its group's, or all four when its
    group is unsure) a neighbour's logit exceeds its own by more than ``pair_error``, its own
    (even ``error`` higher) below where float32 rounds probabilities together: then it is no
    maximum in float32 either."""
    h, w = logit.shape
    lp = np.float64(logit[y, x])
    if lp >= _ROUNDS_TOGETHER - error:
        return False
    for g in range(4):
        if not any_group and g != own:
            continue
        beaten = False
        for sign in (-1, 1):
            yy, xx = y + sign * normals[g, 0], x + sign * normals[g, 1]
            if 0 <= yy < h and 0 <= xx < w:
                lq = np.float64(logit[yy, xx])
                if lq - lp > pair_error:
                    beaten = True
        if not beaten:
            return False
    return True


@numba.njit(cache=True, nogil=True, inline="always")
def _interval(logit: np.ndarray, valid: np.ndarray, error: float, y: int, x: int,
              known: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:  # pragma: no cover
    """[lo, hi] of pixel (y, x)'s float32 probability (0 at an invalid pixel), once."""
    if known[y, x]:
        return
    known[y, x] = True
    if valid[y, x]:
        lo[y, x] = _rounded_sigmoid(np.float64(logit[y, x]) - error)
        hi[y, x] = _rounded_sigmoid(np.float64(logit[y, x]) + error)
    else:
        lo[y, x] = hi[y, x] = np.float32(0.0)


def _to_uint8(range_mm: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, float]:
    """Scale a filled range image to 8 bits: offset at its minimum, >= 1 mm per grey level."""
    filled = fill_missing(range_mm, valid)
    lo = float(filled.min())
    mm_per_level = max(1.0, (float(filled.max()) - lo) / 255.0)
    levels = np.clip(np.rint((filled - lo) / mm_per_level), 0, 255).astype(np.uint8)
    return levels, mm_per_level


def canny_edges(range_mm: np.ndarray, amplitude: np.ndarray | None = None, *,
                low: float = GT_LOW_MM, high: float = GT_HIGH_MM, blur_sigma: float = 1.0,
                min_amplitude: float = 0.0) -> np.ndarray:
    """The paper's baseline: OpenCV Canny on the raw ToF range image scaled to 8 bits.

    The range image is offset to its minimum and scaled to ``max(1, span / 255)`` mm per grey
    level; thresholds are given in mm of step height like :func:`ground_truth_edges` and
    converted to OpenCV's unnormalised Sobel units (``4 * mm / mm_per_level``). A Gaussian blur
    of ``blur_sigma`` pixels (Canny's smoothing, which ``cv2.Canny`` leaves out) precedes it.

    Args:
        range_mm: (H, W) float radial range in mm; NaN / inf / <= 0 = invalid.
        amplitude: optional (H, W) float amplitude; pixels with amplitude <= ``min_amplitude``
            or non-finite are treated as invalid too.
        low, high: hysteresis thresholds in mm of step height.
        blur_sigma: Gaussian sigma in pixels, 0 = no blur.
        min_amplitude: amplitude validity threshold (amplitude unit).

    Returns:
        (H, W) bool edges; never on invalid pixels (invalid pixels are filled by
        :func:`fill_missing` before the detector).
    """
    r = check_array("range_mm", range_mm, ndim=2, dtype_kind="fiu").astype(np.float32)
    _check_thresholds(low, high)
    valid = np.isfinite(r) & (r > 0)
    if amplitude is not None:
        a = check_array("amplitude", amplitude, ndim=2, shape=r.shape, dtype_kind="fiu")
        valid &= np.isfinite(a) & (a > min_amplitude)
    if not valid.any():
        return np.zeros(r.shape, bool)
    levels, mm_per_level = _to_uint8(r, valid)
    if blur_sigma > 0:
        levels = cv2.GaussianBlur(levels, (0, 0), blur_sigma)
    to_cv = 4.0 / mm_per_level
    edges = cv2.Canny(levels, low * to_cv, high * to_cv, L2gradient=True) > 0
    return edges & valid


def canny_score_map(range_mm: np.ndarray, amplitude: np.ndarray | None = None, *,
                    highs: np.ndarray, ratio: float = 0.5, **kwargs: float) -> np.ndarray:
    """Score map whose threshold at ``t`` reproduces ``canny_edges(high=t, low=ratio * t)``.

    Canny's edge set shrinks as both thresholds rise, so ``score = max{t : p is an edge at t}``
    over the given ``highs`` is well defined; feed it to
    :func:`tof_mpd_ros.evaluation.metrics.edge_precision_recall` with ``thresholds=highs``.

    Args:
        range_mm, amplitude: as :func:`canny_edges`.
        highs: (T,) float high thresholds in mm of step height.
        ratio: low / high.
        **kwargs: ``blur_sigma`` / ``min_amplitude`` for :func:`canny_edges`.

    Returns:
        (H, W) float32 score in mm (0 = never an edge).
    """
    score = np.zeros(np.shape(range_mm), np.float32)
    for t in np.sort(np.asarray(highs, dtype=np.float64)):
        edges = canny_edges(range_mm, amplitude, low=ratio * t, high=t, **kwargs)
        score[edges] = t
    return score
