"""The paper's geodesic filter (eq. 1-2): average R_F over the K geodesically nearest pixels.

``R̂(p) = Σ_q w(p,q) R_F(q) / Σ_q w(p,q)``, ``w = exp(-D²(p,q) / (2 σ²))``, over the ``K`` (81)
pixels ``q`` nearest to ``p`` in geodesic distance ``D`` on the pixel grid, ``p`` included.

The grid graph (definitions used everywhere in this module):

* **8-connected**: axis neighbours are ``step`` apart, diagonal ones ``step * √2``, so
  unobstructed distance is the octile distance and the 81 nearest pixels form a near-disc of
  radius ~5 (4-connectivity would give an L1 diamond).
* **Edges are barriers**: no path *enters* an edge pixel. A diagonal move is also blocked when
  both pixels at the corners it cuts are edges, because an 8-connected edge curve (what
  non-maximum suppression produces) crosses a diagonal move exactly there. So "an edge
  separates p and q" means every grid path from p to q enters an edge pixel or cuts such a
  corner; their distance is then ∞.
* **Edge pixels as sources**: a path may *leave* an edge pixel, so the neighbour list of an edge
  pixel holds itself and the nearest pixels on both sides. :func:`geodesic_filter` does not
  average those (that would recreate the over-smoothing at boundaries the filter exists to
  remove): an edge pixel takes the filtered value of the adjacent non-edge pixel whose value is
  closest to its own R_F, i.e. it joins the side it already resembles (the farther side if its
  own R_F is missing).
* **Missing pixels** (``valid`` False / R_F NaN) are never neighbours (they use no slot of K),
  but paths may cross them: a missing measurement is not a boundary, and blocking would starve
  pixels near holes. A missing pixel's own output is filled from its K valid neighbours unless
  ``fill_missing=False``.
* The search stops at ``max_distance`` (default 32 steps, where ``w`` < 1e-50 at σ = 2); lists
  are padded with index -1 and distance ∞ when fewer than K valid pixels are that close.

Exactness and speed: every path length is ``(a + b √2) step`` with integer counts ``a`` of axis
and ``b`` of diagonal moves, so distances are kept as exact ``(a, b)`` pairs and ranked through a
precomputed table; Dijkstra then runs on a bucket queue over those ranks (O(1) push/pop, no
floating-point ties). Within one distance, pixels are ordered by flat index, so results are
deterministic and tie-exact. Pixels whose template footprint (the K nearest offsets on an open
grid) holds no edge, missing pixel or image border take that template instead of a search
(provably the same list; ~60 % of a typical frame), and their weighted means are one
correlation of the frame with that template's kernel (``cv2.filter2D``). Pixels near the image
border whose footprint is cut by the border use a *border template* instead: the K nearest
in-image offsets for their clipped distances to the four borders (one precomputed list per
border class, cached per image size), valid by the same argument since a rectangle keeps octile
distances (another ~10 % of a frame, a quarter of the searches). Written in numba because
neither scipy nor OpenCV offers a K-nearest geodesic search on a pixel grid with early stop
(``scipy.sparse.csgraph.dijkstra`` computes whole rows; the tests use it as the reference).
Kernels run in parallel over image rows (strided, since edges cluster), with work arrays
allocated once per worker chunk, never per pixel: serial GIL-free numba kernels on
``numba.get_num_threads()`` plain Python threads (:func:`_run_chunks`), not numba's OpenMP
``prange``, so no idle OpenMP thread spins against torch's in the same process and the pool is
reset in a forked child. ``cache=True`` keeps the compiled kernels on disk next to this file,
so only the first import on a machine pays the ~15 s compile, not every test run or node start
(delete ``__pycache__`` if numba is upgraded and complains).
"""

from __future__ import annotations

import functools
import math
import threading
from typing import NamedTuple

import cv2
import numba
import numpy as np

from ..errors import InputError
from ..thread_pools import run_chunks
from ..validation import check_array, check_same_shape

DEFAULT_MAX_STEPS = 32.0
# Concurrent calls share the worker pool; one call at a time keeps each call's threads busy.
_KERNEL_LOCK = threading.Lock()
# (dy, dx, is_diagonal) of the 8 moves.
_MOVES = np.array([[-1, -1, 1], [-1, 0, 0], [-1, 1, 1], [0, -1, 0], [0, 1, 0],
                   [1, -1, 1], [1, 0, 0], [1, 1, 1]], dtype=np.int64)


@functools.lru_cache(maxsize=16)
def _rank_table(max_steps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rank every path length ``a + b √2 <= max_steps`` (in steps) and its successors.

    Returns:
        rank_of: (A+1, B+1) int32, rank of length ``a + b √2``, -1 beyond ``max_steps``.
        length: (n_ranks,) float64 length of each rank, in steps, increasing.
        next_axis, next_diag: (n_ranks,) int32 rank after one more axis / diagonal move, -1
            beyond ``max_steps``.
    """
    a_max = math.floor(max_steps)
    b_max = math.floor(max_steps / math.sqrt(2.0))
    a, b = np.meshgrid(np.arange(a_max + 1), np.arange(b_max + 1), indexing="ij")
    length = a + b * math.sqrt(2.0)
    inside = length <= max_steps + 1e-9
    # Distinct (a, b) have distinct lengths (√2 is irrational); argsort gives the ranks.
    order = np.argsort(length[inside], kind="stable")
    rank_of = np.full(length.shape, -1, np.int32)
    ranks = np.empty(order.size, np.int32)
    ranks[order] = np.arange(order.size, dtype=np.int32)
    rank_of[inside] = ranks
    padded = np.pad(rank_of, ((0, 1), (0, 1)), constant_values=-1)
    next_axis = np.empty(order.size, np.int32)
    next_diag = np.empty(order.size, np.int32)
    next_axis[ranks] = padded[a[inside] + 1, b[inside]]
    next_diag[ranks] = padded[a[inside], b[inside] + 1]
    return rank_of, np.sort(length[inside]), next_axis, next_diag


def _template(k: int, width: int,
              rank_of: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
    """The K nearest offsets on an unobstructed grid, in (distance, flat index) order.

    Returns:
        offsets: (k,) int64 flat index offsets (``dy * width + dx``).
        ranks: (k,) int32 distance ranks.
        dy, dx: (k,) int64 row / column offsets (the template's footprint).
        usable: False when the K-th distance exceeds the search limit (never use the template).
    """
    r = math.ceil(math.sqrt(k)) + 1  # a (2r+1)² square holds more than k pixels
    dy, dx = (g.ravel() for g in np.mgrid[-r:r + 1, -r:r + 1])
    a = np.abs(np.abs(dy) - np.abs(dx))
    b = np.minimum(np.abs(dy), np.abs(dx))
    order = np.lexsort((dy * width + dx, a + b * math.sqrt(2.0)))[:k]
    dy, dx, a, b = dy[order], dx[order], a[order], b[order]
    inside = (a < rank_of.shape[0]) & (b < rank_of.shape[1])
    ranks = np.where(inside, rank_of[np.minimum(a, rank_of.shape[0] - 1),
                                     np.minimum(b, rank_of.shape[1] - 1)], -1).astype(np.int32)
    return dy * width + dx, ranks, dy, dx, bool((ranks >= 0).all())


@functools.lru_cache(maxsize=16)
def _template_for(k: int, width: int, max_steps: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
    """:func:`_template` for a search limit, cached (the same for every frame of a stream)."""
    return _template(k, width, _rank_table(max_steps)[0])


def _template_ok(obstacle: np.ndarray, dy: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """(H, W) bool: the template footprint around the pixel is inside and obstacle-free.

    Exactness: every template pixel keeps its octile distance when the footprint is clear,
    because the pixels (and cut corners) along an octile shortest path are strictly closer to
    the source, hence in the footprint too; obstacles only lengthen the paths to every other
    pixel. Each footprint row is checked as one interval with a row-wise cumulative sum.
    """
    h, w = obstacle.shape
    r = int(max(np.abs(dy).max(), np.abs(dx).max()))
    padded = np.pad(obstacle, r, constant_values=True)  # outside the image is an obstacle
    cum = np.zeros((h + 2 * r, w + 2 * r + 1), np.int32)
    np.cumsum(padded, axis=1, out=cum[:, 1:])
    count = np.zeros((h, w), np.int32)
    for row in np.unique(dy):
        lo, hi = dx[dy == row].min(), dx[dy == row].max()
        rows = slice(r + row, r + row + h)
        count += cum[rows, r + hi + 1:r + hi + 1 + w] - cum[rows, r + lo:r + lo + w]
    return count == 0


@functools.lru_cache(maxsize=16)
def _border_templates(k: int, h: int, w: int, max_steps: float
                      ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """The K nearest in-image offsets of a pixel near the border, per border class.

    A pixel's class is ``(cy, cx)`` in ``[0, 2r]²``: ``cy`` = its row if it is within ``r`` of
    the top, ``2r - (distance to the bottom)`` if within ``r`` of the bottom, else ``r``
    (likewise ``cx``); ``(r, r)`` is the open template's class. Within the image rectangle an
    unobstructed octile shortest path never leaves the bounding box of its ends, so the same
    exactness argument as the open template holds: when none of the class's K pixels is an
    obstacle (edge or missing), they are the pixel's K nearest, at octile distance. ``r`` is
    the smallest window radius exceeding every class's K-th distance.

    Returns:
        r: class window radius (0 = border templates unusable: image narrower than 2r).
        offsets: (n_classes, k) int64 flat offsets in (distance, flat index) order.
        ranks: (n_classes, k) int32 distance ranks.
        usable: (n_classes,) bool.
    """
    rank_of = _rank_table(max_steps)[0]
    empty = (0, np.zeros((0, k), np.int64), np.zeros((0, k), np.int32), np.zeros(0, bool))
    r = math.ceil(math.sqrt(4.0 * k / math.pi)) + 1       # a quarter disc of k pixels fits
    while True:
        if h < 2 * r or w < 2 * r:
            return empty
        dy, dx = (g.ravel() for g in np.mgrid[-r:r + 1, -r:r + 1])
        a = np.abs(np.abs(dy) - np.abs(dx))
        b = np.minimum(np.abs(dy), np.abs(dx))
        length = a + b * math.sqrt(2.0)
        side = 2 * r + 1
        offsets = np.zeros((side * side, k), np.int64)
        ranks = np.full((side * side, k), -1, np.int32)
        usable = np.zeros(side * side, bool)
        too_small = False
        everywhere = np.ones(dy.shape, bool)
        for cy in range(side):
            y_ok = (dy >= -cy) if cy < r else (dy <= 2 * r - cy) if cy > r else everywhere
            for cx in range(side):
                x_ok = (dx >= -cx) if cx < r else (dx <= 2 * r - cx) if cx > r else everywhere
                cand = np.flatnonzero(y_ok & x_ok)
                order = cand[np.lexsort((dy[cand] * w + dx[cand], length[cand]))][:k]
                c = cy * side + cx
                if order.size < k:
                    continue
                if length[order[-1]] >= r:   # pixels beyond the window could be as close
                    too_small = True
                    break
                ai, bi = a[order], b[order]
                if (ai >= rank_of.shape[0]).any() or (bi >= rank_of.shape[1]).any():
                    continue                  # beyond the search limit: never a template
                rk = rank_of[ai, bi]
                if (rk < 0).any():
                    continue
                offsets[c] = dy[order] * w + dx[order]
                ranks[c] = rk
                usable[c] = True
            if too_small:
                break
        if not too_small:
            return r, offsets, ranks, usable
        r += 1


class Graph(NamedTuple):
    """The grid graph of one frame as the compiled kernels read it (see the module doc).

    Flat pixel index ``p = y * w + x`` throughout.

    Attributes:
        h, w: image rows and columns.
        moves_ok: (H*W,) uint8 bit mask of the moves allowed from each pixel (bit i =
            ``_MOVES[i]``).
        move_off: (8,) int64 flat offset of each move; move_diag: (8,) bool, diagonal moves.
        valid: (H*W,) bool pixels that may be neighbours.
        k: neighbours wanted per pixel.
        next_axis, next_diag: (n_ranks,) int32 distance rank after one more axis / diagonal
            move (-1 beyond the search limit), from :func:`_rank_table`.
        pool_size: entries of a worker's bucket-queue pool (8 per settled pixel).
        tmpl_ok: (H*W,) bool pixels whose open template applies (clear footprint).
        tmpl_off: (k,) int64 flat offsets of the open template; tmpl_rank: (k,) int32 ranks.
        obstacle: (H*W,) bool edge or missing pixels.
        border_r: border-class window radius (0 = no border templates).
        cls_ok: (n_classes,) bool usable border classes; cls_off: (n_classes, k) int64
            offsets; cls_rank: (n_classes, k) int32 ranks (:func:`_border_templates`).
    """

    h: int
    w: int
    moves_ok: np.ndarray
    move_off: np.ndarray
    move_diag: np.ndarray
    valid: np.ndarray
    k: int
    next_axis: np.ndarray
    next_diag: np.ndarray
    pool_size: int
    tmpl_ok: np.ndarray
    tmpl_off: np.ndarray
    tmpl_rank: np.ndarray
    obstacle: np.ndarray
    border_r: int
    cls_ok: np.ndarray
    cls_off: np.ndarray
    cls_rank: np.ndarray


class SearchWork(NamedTuple):
    """One worker's arrays for :func:`_knn_one` (allocated once per chunk, never per pixel).

    Attributes:
        state: (H*W,) int32 stamps, ``2 sid`` reached / ``2 sid + 1`` settled (must start
            below every source's stamp: zeros).
        rank: (H*W,) int32 best distance rank found (read only where a stamp says written).
        bhead: (n_ranks,) int32 head of each bucket's list in the pool.
        bstamp: (n_ranks,) int32 source stamp of each bucket (zeros at start).
        pool_node, pool_next: (pool_size,) int32 bucket lists (node, next entry).
        cand: (pool_size,) int32 a bucket's pixels being settled, sorted by index.
    """

    state: np.ndarray
    rank: np.ndarray
    bhead: np.ndarray
    bstamp: np.ndarray
    pool_node: np.ndarray
    pool_next: np.ndarray
    cand: np.ndarray


@numba.njit(cache=True, nogil=True)
def _search_work(g: Graph) -> SearchWork:  # pragma: no cover
    """Fresh :class:`SearchWork` for ``g``."""
    n = g.h * g.w
    n_ranks = g.next_axis.shape[0]
    return SearchWork(np.zeros(n, np.int32), np.empty(n, np.int32),
                      np.empty(n_ranks, np.int32), np.zeros(n_ranks, np.int32),
                      np.empty(g.pool_size, np.int32), np.empty(g.pool_size, np.int32),
                      np.empty(g.pool_size, np.int32))


# Inlined (numba IR): called per pixel, and a call passes the whole Graph flattened into
# scalar arguments (~5 % of the filter).
@numba.njit(cache=True, nogil=True, inline="always")
def _border_class(p, g):  # pragma: no cover
    """Border class of pixel ``p`` when its border template applies (clear footprint), else -1."""
    h, w, r = g.h, g.w, g.border_r
    cls_ok, cls_off, obstacle = g.cls_ok, g.cls_off, g.obstacle
    if cls_ok.shape[0] == 0:
        return -1
    y = p // w
    x = p - y * w
    cy = y if y < r else (2 * r - (h - 1 - y) if h - 1 - y < r else r)
    cx = x if x < r else (2 * r - (w - 1 - x) if w - 1 - x < r else r)
    if cy == r and cx == r:
        return -1
    c = cy * (2 * r + 1) + cx
    if not cls_ok[c]:
        return -1
    for i in range(cls_off.shape[1]):
        if obstacle[p + cls_off[c, i]]:
            return -1
    return c


def _allowed_moves(edge: np.ndarray) -> np.ndarray:
    """(H, W) uint8 bit mask of the moves (bit i = ``_MOVES[i]``) a path may take from a pixel.

    A move is allowed when it stays in the image, does not enter an edge pixel and, if
    diagonal, does not cut between two edge pixels.
    """
    h, w = edge.shape
    pad = np.pad(edge, 1, constant_values=True)  # outside the image = barrier
    mask = np.zeros((h, w), np.uint8)
    for i, (dy, dx, diag) in enumerate(_MOVES):
        ok = ~pad[1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
        if diag:
            ok &= ~(pad[1:1 + h, 1 + dx:1 + dx + w] & pad[1 + dy:1 + dy + h, 1:1 + w])
        mask |= ok.astype(np.uint8) << np.uint8(i)
    return mask


# One function: the bucket loop is the hot loop, kept whole so its locals stay in registers.
@numba.njit(cache=True, nogil=True)
def _knn_one(src, g, work, out_idx, out_rank):  # pragma: no cover
    """Bucket-queue Dijkstra from ``src`` on graph ``g`` (:class:`Graph`) with ``work``
    (:class:`SearchWork`); writes up to k (index, rank); returns the count.

    ``state[v]`` is ``2 sid`` once v is reached from this source and ``2 sid + 1`` once settled
    (``sid = src + 1``); sources of one worker increase, so older stamps are always smaller and
    nothing is reset between sources.
    """
    moves_ok, move_off, move_diag, valid = g.moves_ok, g.move_off, g.move_diag, g.valid
    k, next_axis, next_diag = g.k, g.next_axis, g.next_diag
    state, rank, bhead, bstamp = work.state, work.rank, work.bhead, work.bstamp
    pool_node, pool_next, cand = work.pool_node, work.pool_next, work.cand
    sid = src + 1
    reached = 2 * sid
    settled = reached + 1
    state[src] = reached
    rank[src] = 0
    bstamp[0] = sid
    pool_node[0] = src
    pool_next[0] = -1
    bhead[0] = 0
    n_pool = 1
    n_out = 0
    for r in range(bhead.shape[0]):
        if bstamp[r] != sid:
            continue
        # Settle the whole bucket at once, in flat-index order (deterministic tie-breaking).
        m = 0
        e = bhead[r]
        while e != -1:
            v = pool_node[e]
            if state[v] == reached and rank[v] == r:
                state[v] = settled
                j = m
                while j > 0 and cand[j - 1] > v:  # insertion sort; buckets hold a few pixels
                    cand[j] = cand[j - 1]
                    j -= 1
                cand[j] = v
                m += 1
            e = pool_next[e]
        for i in range(m):
            v = cand[i]
            if valid[v]:
                out_idx[n_out] = v
                out_rank[n_out] = r
                n_out += 1
                if n_out == k:
                    return n_out
            mask = moves_ok[v]
            r_axis = next_axis[r]
            r_diag = next_diag[r]
            for mi in range(8):
                if not (mask >> mi) & 1:
                    continue
                nr = r_diag if move_diag[mi] else r_axis
                if nr < 0:
                    continue
                u = v + move_off[mi]
                su = state[u]
                if su == settled:
                    continue
                if su < reached or nr < rank[u]:
                    state[u] = reached
                    rank[u] = nr
                    if bstamp[nr] != sid:
                        bstamp[nr] = sid
                        bhead[nr] = -1
                    pool_node[n_pool] = u
                    pool_next[n_pool] = bhead[nr]
                    bhead[nr] = n_pool
                    n_pool += 1
    return n_out


@numba.njit(cache=True, nogil=True)
def _knn_all(first, stride, n_chunks, g, out_idx, out_rank):  # pragma: no cover
    """K nearest valid pixels of the pixels of chunks ``first, first + stride, ...`` (chunk c
    = rows c, c + n_chunks, ...) of graph ``g`` (:class:`Graph`)."""
    h, w, k = g.h, g.w, g.k
    for c in range(first, n_chunks, stride):
        work = _search_work(g)   # once per chunk, never per pixel
        for y in range(c, h, n_chunks):
            for p in range(y * w, (y + 1) * w):
                if g.tmpl_ok[p]:
                    for i in range(k):
                        out_idx[p, i] = p + g.tmpl_off[i]
                        out_rank[p, i] = g.tmpl_rank[i]
                    continue
                cls = _border_class(p, g)
                if cls >= 0:
                    for i in range(k):
                        out_idx[p, i] = p + g.cls_off[cls, i]
                        out_rank[p, i] = g.cls_rank[cls, i]
                else:
                    _knn_one(p, g, work, out_idx[p], out_rank[p])


@numba.njit(cache=True, nogil=True)
def _filter_all(first, stride, n_chunks, g, values, weight_of_rank, skip, open_mean,
                out):  # pragma: no cover
    """Fused search + weighted mean: out[p] = Σ w R / Σ w over p's K nearest, NaN if none
    (chunks ``first, first + stride, ...`` as :func:`_knn_all`); a pixel whose open template
    applies takes ``open_mean`` (that template's mean, :func:`_open_template_mean`)."""
    h, w, k = g.h, g.w, g.k
    tmpl_ok = g.tmpl_ok
    cls_off, cls_rank = g.cls_off, g.cls_rank
    for c in range(first, n_chunks, stride):
        work = _search_work(g)   # once per chunk, never per pixel
        idx = np.zeros(k, np.int32)
        rnk = np.zeros(k, np.int32)
        for y in range(c, h, n_chunks):
            for p in range(y * w, (y + 1) * w):
                if skip[p]:
                    out[p] = np.nan
                    continue
                num = 0.0
                den = 0.0
                if tmpl_ok[p]:
                    out[p] = open_mean[p]
                    continue
                cls = _border_class(p, g)
                if cls >= 0:
                    for i in range(k):
                        wgt = weight_of_rank[cls_rank[cls, i]]
                        num += wgt * values[p + cls_off[cls, i]]
                        den += wgt
                else:
                    m = _knn_one(p, g, work, idx, rnk)
                    for i in range(m):
                        wgt = weight_of_rank[rnk[i]]
                        num += wgt * values[idx[i]]
                        den += wgt
                out[p] = num / den if den > 0.0 else np.nan


def _max_steps(step: float, max_distance: float | None) -> float:
    """The search limit in steps (``max_distance / step``; None: ``DEFAULT_MAX_STEPS``).

    Raises:
        InputError: a step that is not finite and > 0, or a limit outside [1, 1024] steps.
    """
    if not (np.isfinite(step) and step > 0):
        raise InputError(f"step: expected a finite value > 0, got {step!r}")
    max_steps = DEFAULT_MAX_STEPS if max_distance is None else max_distance / step
    if not (np.isfinite(max_steps) and 1.0 <= max_steps <= 1024.0):
        raise InputError(f"max_distance: expected between step and 1024 * step, got "
                         f"{max_distance!r} (step {step})")
    return float(max_steps)


def _prepare(edges: np.ndarray, valid: np.ndarray, k: int, step: float,
             max_distance: float | None) -> tuple[Graph, np.ndarray]:
    """Validate and build the kernels' :class:`Graph`; also return each rank's length (steps)."""
    e = check_array("edges", edges, ndim=2, dtype_kind="bui")
    v = check_array("valid", valid, ndim=2, dtype_kind="bui")
    check_same_shape(edges=e, valid=v)
    if not (isinstance(k, (int, np.integer)) and k >= 1):
        raise InputError(f"k: expected an integer >= 1, got {k!r}")
    max_steps = _max_steps(step, max_distance)
    h, w = e.shape
    edge = e.astype(bool)
    ok = v.astype(bool)
    _rank_of, length, next_axis, next_diag = _rank_table(float(max_steps))
    off, trank, tdy, tdx, usable = _template_for(int(k), w, float(max_steps))
    obstacle = edge | ~ok
    tmpl_ok = (_template_ok(obstacle, tdy, tdx) & usable).ravel()
    b_r, cls_off, cls_rank, cls_ok = _border_templates(int(k), h, w, float(max_steps))
    move_off = (_MOVES[:, 0] * w + _MOVES[:, 1]).astype(np.int64)
    move_diag = _MOVES[:, 2].astype(np.bool_)
    side = 2 * math.floor(max_steps) + 1
    pool_size = 8 * min(h * w, side * side) + 8  # each settled pixel pushes at most 8 entries
    graph = Graph(h=h, w=w, moves_ok=_allowed_moves(edge).ravel(), move_off=move_off,
                  move_diag=move_diag, valid=np.ascontiguousarray(ok.ravel()), k=int(k),
                  next_axis=next_axis, next_diag=next_diag, pool_size=pool_size,
                  tmpl_ok=tmpl_ok, tmpl_off=off.astype(np.int64), tmpl_rank=trank,
                  obstacle=np.ascontiguousarray(obstacle.ravel()), border_r=int(b_r),
                  cls_ok=cls_ok, cls_off=cls_off, cls_rank=cls_rank)
    return graph, length


def _n_chunks(h: int) -> int:
    return max(1, min(h, 4 * numba.get_num_threads()))  # several per thread: edges cluster


def _run_chunks(kernel: object, n_chunks: int, *args: object) -> None:
    """Run ``kernel(first, stride, n_chunks, *args)`` on ``numba.get_num_threads()`` threads
    (:func:`~tof_mpd_ros.thread_pools.run_chunks`: the thread count follows
    ``numba.set_num_threads``), one call at a time."""
    with _KERNEL_LOCK:
        run_chunks("geodesic", numba.get_num_threads(), kernel, n_chunks, *args)


def geodesic_neighbours(edges: np.ndarray, valid: np.ndarray, *, k: int = 81, step: float = 1.0,
                        max_distance: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The K geodesically nearest valid pixels of every pixel (see the module doc for the graph).

    Args:
        edges: (H, W) bool, True on edge pixels (barriers).
        valid: (H, W) bool, True where the pixel may be a neighbour (R_F finite).
        k: neighbours per pixel (the paper: 81), the pixel itself included when valid.
        step: distance between axis neighbours (diagonals: ``step * √2``), any unit.
        max_distance: search radius, same unit as ``step``; None = 32 steps.

    Returns:
        indices: (H*W, k) int32 flat pixel indices (``row * W + col``) in increasing distance,
            ties by increasing index; -1 padding when fewer than k valid pixels are reachable.
        distances: (H*W, k) float32 geodesic distances in the unit of ``step``; inf padding.
    """
    graph, length = _prepare(edges, valid, k, step, max_distance)
    n = graph.h * graph.w
    idx = np.full((n, k), -1, np.int32)
    rank = np.full((n, k), -1, np.int32)
    _run_chunks(_knn_all, _n_chunks(graph.h), graph, idx, rank)
    lengths = np.append(length * step, np.inf).astype(np.float32)  # rank -1 -> inf
    return idx, lengths[rank]


def _open_template_mean(values: np.ndarray, k: int, max_steps: float,
                        weight_of_rank: np.ndarray) -> np.ndarray:
    """The filter's output at every pixel whose open template applies, as one correlation.

    Where the template's footprint is clear (``Graph.tmpl_ok``), a pixel's K nearest are the
    template's offsets at their octile distances, so its weighted mean is a fixed kernel
    applied there: one ``cv2.filter2D`` over the frame instead of K gathers per pixel (most of
    a frame's pixels, and most of the filter's time before). Elsewhere the result is not read.

    Args:
        values: (H, W) float64 R_F in mm, 0 where missing.
        k, max_steps: the search's K and limit in steps (select the template).
        weight_of_rank: (n_ranks,) float64 weight of each distance rank.

    Returns:
        (H, W) float64 weighted means in mm (meaningful only where the template applies).
    """
    _off, rank, dy, dx, usable = _template_for(int(k), values.shape[1], max_steps)
    if not usable:                    # the template is never used: nothing to compute
        return values
    r = int(max(np.abs(dy).max(), np.abs(dx).max()))
    kernel = np.zeros((2 * r + 1, 2 * r + 1), np.float64)
    kernel[dy + r, dx + r] = weight_of_rank[rank]
    kernel /= kernel.sum()
    return cv2.filter2D(values, cv2.CV_64F, kernel, anchor=(r, r),
                        borderType=cv2.BORDER_CONSTANT)


def _snap_edge_pixels(filtered: np.ndarray, range_mm: np.ndarray, edges: np.ndarray,
                      fill_missing: bool) -> np.ndarray:
    """Give each edge pixel the filtered value of its most similar non-edge 8-neighbour.

    Args:
        filtered: (H, W) float64 filter output, NaN at edge pixels.
        range_mm: (H, W) float R_F in mm, NaN = missing.
        edges: (H, W) bool edge map.
        fill_missing: whether a missing edge pixel may take a value.

    Returns:
        (H, W) float32, ``filtered`` with edge pixels set.
    """
    h, w = filtered.shape
    out = filtered.astype(np.float32)
    ey, ex = np.nonzero(edges)
    if ey.size == 0:
        return out
    ny = ey[None, :] + _MOVES[:, :1]  # (8, n_edges)
    nx = ex[None, :] + _MOVES[:, 1:2]
    inside = (ny >= 0) & (ny < h) & (nx >= 0) & (nx < w)
    ny, nx = np.clip(ny, 0, h - 1), np.clip(nx, 0, w - 1)
    side = np.where(inside & ~edges[ny, nx], filtered[ny, nx], np.nan)
    own = range_mm[ey, ex].astype(np.float64)
    usable = np.isfinite(side)
    # Own value missing: take the farther side (occlusion shadows lie on the background side).
    cost = np.where(np.isfinite(own), np.abs(side - own), -side)
    best = side[np.argmin(np.where(usable, cost, np.inf), axis=0), np.arange(ey.size)]
    # No usable neighbour: keep the pixel's own R_F.
    snapped = np.where(usable.any(axis=0), best, own)
    if not fill_missing:
        snapped = np.where(np.isfinite(own), snapped, np.nan)
    out[ey, ex] = snapped
    return out


def geodesic_filter(range_mm: np.ndarray, edges: np.ndarray, *, k: int = 81, sigma: float = 2.0,
                    step: float = 1.0, max_distance: float | None = None,
                    fill_missing: bool = True) -> np.ndarray:
    """The paper's geodesic filter of the range-recovery output R_F (eq. 1).

    Args:
        range_mm: (H, W) float R_F, radial range in mm; NaN / inf = missing.
        edges: (H, W) bool boundary map (from G); barriers for the geodesic distance.
        k: neighbours per pixel (81).
        sigma: Gaussian bandwidth of ``w = exp(-D² / (2 σ²))``, same unit as ``step`` (2).
        step: distance between axis neighbours (1 pixel).
        max_distance: search radius (None = 32 steps).
        fill_missing: give missing pixels the average of their valid geodesic neighbours
            (else they stay NaN).

    Returns:
        (H, W) float32 filtered radial range in mm; NaN where no valid pixel is within reach
        (or a missing pixel with ``fill_missing=False``). Edge pixels: see the module doc.
    """
    r = check_array("range_mm", range_mm, ndim=2, dtype_kind="fiu")
    e = check_array("edges", edges, ndim=2, shape=r.shape, dtype_kind="bui").astype(bool)
    if not (np.isfinite(sigma) and sigma > 0):
        raise InputError(f"sigma: expected a finite value > 0, got {sigma!r}")
    valid = np.isfinite(r)
    values = np.where(valid, r, 0.0).astype(np.float64).ravel()
    graph, length = _prepare(e, valid, k, step, max_distance)
    d = length * step
    weight_of_rank = np.exp(-(d * d) / (2.0 * sigma * sigma))
    # Edge pixels are snapped afterwards; missing ones are only filled on request.
    skip = e | ~valid if not fill_missing else e
    open_mean = _open_template_mean(values.reshape(r.shape), k, _max_steps(step, max_distance),
                                    weight_of_rank)
    out = np.empty(r.size, np.float64)
    _run_chunks(_filter_all, _n_chunks(r.shape[0]), graph, values, weight_of_rank,
                skip.ravel(), open_mean.ravel(), out)
    filtered = out.reshape(r.shape)
    return _snap_edge_pixels(filtered, r, e, fill_missing)
