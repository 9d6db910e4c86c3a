"""A straightforward per-pixel oracle of :func:`tof_mpd_ros.correction.pipeline.correct`.

Test code, not shipped: it only keeps the production path honest (``test/correction``,
``benchmarks/bench_pipeline.py``).

Same maths as the production path, written to be read and checked rather than to be fast
(~8 s of CPU per 180x140 frame, three quarters of it in the per-pixel Dijkstra):

1. **calibration**: ``c0 + c1 R + c2 a(A)`` pixel by pixel in float32 scalars;
2. **encoding**: for every pixel its 11x11 window is cut out of the NaN-padded planes and turned
   into ``[x_R x_A b_R b_A]`` (280 values, paper eq. 3) exactly as the encoding module's
   docstring defines it (float32, log amplitude rounded from float64, bins by floor);
3. **F** and each of the **4 G heads**: plain matrix-vector products per pixel with the model's
   weights, in float64 (``relu(W x + b)`` layer after layer, F's one-hot terms as part of the
   280-vector, G's edge probability ``softmax(logits)[1]``), rounded to float32 at the end;
4. **edges**: the (4, H, W) head probabilities ->
   :func:`~tof_mpd_ros.correction.edges.edge_map_from_responses` (max over the heads, NMS,
   staircase thinning, hysteresis; it *is* the definition, so it is reused, not rewritten; the
   production path enters the same code through ``edge_map_from_best`` with the maximum and its
   group);
5. **geodesic filter**: a textbook Dijkstra per pixel with :mod:`heapq` on the graph of
   :mod:`tof_mpd_ros.correction.geodesic` (8-connected, axis step 1 and diagonal √2, no path
   enters an edge pixel, a diagonal move is blocked when both corner pixels it cuts are edges,
   missing pixels may be crossed but are never neighbours, search radius 32 steps, ties by flat
   index), then the Gaussian-weighted mean over the K nearest valid pixels and the edge-pixel
   snapping rule.

Intentional differences from the production path, none of which is visible in the outputs:

* the networks accumulate in float64 (production: float32 GEMMs in another summation order), so
  F agrees to ~1e-5 mm and the probabilities to ~1 float32 ulp. An edge could in principle
  differ where two neighbouring probabilities are within an ulp of each other across a
  non-maximum-suppression or hysteresis comparison; the tests and the benchmark check that the
  edge maps are identical;
* path lengths are kept as integer counts ``(a, b)`` of axis and diagonal moves (length
  ``a + b √2``) so equal geodesic distances compare equal; the production kernel does the same
  through a rank table. A float accumulation (``d + 1.0``, ``d + √2``) could order two pixels at
  the same true distance differently depending on the path and pick another K-th neighbour;
* invalid centre pixels get no one-hot bin (the encoding module's definition); the production
  networks look up bin 0 for them. Their outputs are NaN either way.

Every stage is a separate function taking an optional list of pixels, so the benchmark can time
the slow stages on a sample of pixels and extrapolate.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from tof_mpd_ros.calibration.intrinsic import IntrinsicCalibration
from tof_mpd_ros.correction.edges import edge_map_from_responses
from tof_mpd_ros.correction.encoding import EncodingConfig
from tof_mpd_ros.correction.geodesic import DEFAULT_MAX_STEPS
from tof_mpd_ros.correction.pipeline import CorrectionModel, CorrectionResult, check_frame_pair
from tof_mpd_ros.errors import InputError

SQRT2 = math.sqrt(2.0)
# (dy, dx) of the 8 moves, in the order geodesic.py uses (it matters for edge snapping ties).
MOVES = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


def _f32(x: float) -> np.float32:
    return np.float32(x)


# ---------------------------------------------------------------------------------------------
# 1. calibration


def reference_calibration(calibration: IntrinsicCalibration, range_mm: np.ndarray,
                          amplitude: np.ndarray) -> np.ndarray:
    """Per-pixel ``c0 + c1 R + c2 a(A)`` in float32 scalars, NaN where the input is invalid.

    Args:
        calibration: the per-pixel model.
        range_mm: (H, W) raw radial range in mm.
        amplitude: (H, W) raw amplitude.

    Returns:
        (H, W) float32 calibrated range in mm.
    """
    h, w = range_mm.shape
    out = np.full((h, w), np.nan, np.float32)
    for y in range(h):
        for x in range(w):
            r = np.float32(range_mm[y, x])
            a = np.float32(amplitude[y, x])
            if not (np.isfinite(r) and np.isfinite(a) and r > 0 and a > 0):
                continue
            af = a if calibration.amplitude_term == "linear" else np.float32(1.0) / a
            out[y, x] = (calibration.c0[y, x] + calibration.c1[y, x] * r
                         + calibration.c2[y, x] * af)
    return out


# ---------------------------------------------------------------------------------------------
# 2. encoding


@dataclass
class Planes:
    """NaN-padded planes the patches are cut from (pad = P // 2 on each side).

    Attributes:
        range_mm: (H + P - 1, W + P - 1) float32 calibrated range, NaN = invalid/outside.
        log_amplitude: same shape, float32 natural-log amplitude, NaN = invalid/outside.
        amplitude: (H, W) float32 linear amplitude (for b_A).
        valid: (H, W) bool, finite range and amplitude, both > 0.
    """

    range_mm: np.ndarray
    log_amplitude: np.ndarray
    amplitude: np.ndarray
    valid: np.ndarray


def reference_planes(calibrated_mm: np.ndarray, amplitude: np.ndarray,
                     config: EncodingConfig) -> Planes:
    """Validity and the padded planes of a calibrated (H, W) frame, pixel by pixel."""
    h, w = calibrated_mm.shape
    pad = config.patch_size // 2
    r_pad = np.full((h + 2 * pad, w + 2 * pad), np.nan, np.float32)
    la_pad = np.full_like(r_pad, np.nan)
    valid = np.zeros((h, w), bool)
    amp = np.asarray(amplitude, np.float32)
    for y in range(h):
        for x in range(w):
            r, a = np.float32(calibrated_mm[y, x]), amp[y, x]
            if np.isfinite(r) and np.isfinite(a) and r > 0 and a > 0:
                valid[y, x] = True
                r_pad[y + pad, x + pad] = r
                # Log in float64, rounded to float32 (the encoding's definition).
                la_pad[y + pad, x + pad] = np.float32(math.log(float(a)))
    return Planes(r_pad, la_pad, amp, valid)


def _bin(value: np.float32, lo: float, hi: float, n_bins: int) -> int:
    """Uniform bin of ``value`` over [lo, hi), clamped to the first / last bin (float32)."""
    pos = (value - _f32(lo)) * _f32(n_bins / (hi - lo))
    return int(min(max(math.floor(pos), 0), n_bins - 1))


def reference_encode_pixel(planes: Planes, y: int, x: int, config: EncodingConfig
                           ) -> np.ndarray:
    """``[x_R x_A b_R b_A]`` of pixel (y, x): (2 M + 2 n_bins,) float32, zero if invalid."""
    p = config.patch_size
    m = config.n_neighbours
    nb = config.n_bins
    out = np.zeros(2 * m + 2 * nb, np.float32)
    if not planes.valid[y, x]:
        return out
    for col, plane, clip in ((0, planes.range_mm, config.range_clip_mm),
                             (m, planes.log_amplitude, config.amplitude_log_clip)):
        window = plane[y:y + p, x:x + p].ravel()             # row-major, centre at M // 2
        centre = window[m // 2]
        neighbours = np.delete(window, m // 2)
        diff = np.clip(neighbours - centre, -_f32(clip), _f32(clip)) * _f32(0.5 / _f32(clip))
        out[col:col + m] = np.nan_to_num(diff, nan=0.0)       # invalid / outside -> 0
    r = planes.range_mm[y + p // 2, x + p // 2]
    out[2 * m + _bin(r, config.range_min_mm, config.range_max_mm, nb)] = 1.0
    out[2 * m + nb + _bin(planes.amplitude[y, x], config.amplitude_min, config.amplitude_max,
                          nb)] = 1.0
    return out


def reference_encode(calibrated_mm: np.ndarray, amplitude: np.ndarray, config: EncodingConfig,
                     pixels: Sequence[tuple[int, int]] | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Encode pixels one at a time.

    Args:
        calibrated_mm: (H, W) float32 calibrated range in mm, NaN = invalid.
        amplitude: (H, W) float amplitude.
        config: encoding constants.
        pixels: (y, x) pairs to encode; None = all, row-major.

    Returns:
        ``(features, valid)``: (N, 280) float32 and the (H, W) bool validity mask.
    """
    planes = reference_planes(calibrated_mm, amplitude, config)
    h, w = calibrated_mm.shape
    pts = [(y, x) for y in range(h) for x in range(w)] if pixels is None else pixels
    feats = np.zeros((len(pts), config.n_features), np.float32)
    for i, (y, x) in enumerate(pts):
        feats[i] = reference_encode_pixel(planes, y, x, config)
    return feats, planes.valid


# ---------------------------------------------------------------------------------------------
# 3. networks


@dataclass
class ReferenceWeights:
    """The networks' weights as float64 numpy matrices (layer ``y = W x + b``).

    Attributes:
        range_layers: F's layers, [(W (out, in), b (out,))], ReLU between them.
        target_clip_mm: T, F's output scale in mm.
        boundary_heads: per G head, its three layers [(W, b)] (240 -> 40 -> 20 -> 2).
    """

    range_layers: list[tuple[np.ndarray, np.ndarray]]
    target_clip_mm: float
    boundary_heads: list[list[tuple[np.ndarray, np.ndarray]]]

    @classmethod
    def from_model(cls, model: CorrectionModel) -> ReferenceWeights:
        """Read the weights out of the model's torch modules."""

        def np64(t: torch.Tensor) -> np.ndarray:
            return t.detach().cpu().double().numpy()

        f = [(np64(layer.weight), np64(layer.bias)) for layer in model.range_net.layers]
        g = model.boundary_nets
        h1 = g.hidden[0]
        heads = []
        for k in range(g.n_heads):
            w1 = np64(g.first.weight)[k * h1:(k + 1) * h1]
            b1 = np64(g.first.bias)[k * h1:(k + 1) * h1]
            heads.append([(w1, b1), (np64(g.w2[k]).T, np64(g.b2[k, 0])),
                          (np64(g.w3[k]).T, np64(g.b3[k, 0]))])
        return cls(f, float(model.range_net.target_clip_mm), heads)


def _mlp(layers: list[tuple[np.ndarray, np.ndarray]], x: np.ndarray) -> np.ndarray:
    """Matrix-vector products with ReLU between layers (none after the last)."""
    for i, (w, b) in enumerate(layers):
        x = w @ x + b
        if i < len(layers) - 1:
            x = np.maximum(x, 0.0)
    return x


def reference_range_net(weights: ReferenceWeights, features: np.ndarray) -> np.ndarray:
    """F per pixel: (N, 280) float32 features -> (N,) float32 correction in mm."""
    out = np.empty(features.shape[0], np.float32)
    n_in = weights.range_layers[0][0].shape[1]
    for i in range(features.shape[0]):
        x = features[i, :n_in].astype(np.float64)
        out[i] = _mlp(weights.range_layers, x)[0] * weights.target_clip_mm
    return out


def reference_boundary_nets(weights: ReferenceWeights, features: np.ndarray) -> np.ndarray:
    """The 4 G heads per pixel: (N, >= 240) float32 features -> (N, 4) float32 P(edge)."""
    n_in = weights.boundary_heads[0][0][0].shape[1]
    out = np.empty((features.shape[0], len(weights.boundary_heads)), np.float32)
    for i in range(features.shape[0]):
        x = features[i, :n_in].astype(np.float64)
        for k, head in enumerate(weights.boundary_heads):
            logits = _mlp(head, x)
            out[i, k] = 1.0 / (1.0 + math.exp(logits[0] - logits[1]))   # softmax(...)[1]
    return out


# ---------------------------------------------------------------------------------------------
# 5. geodesic filter


def reference_knn(src: int, edges: np.ndarray, valid: np.ndarray, k: int,
                  max_steps: float = DEFAULT_MAX_STEPS) -> list[tuple[int, int, int]]:
    """The K geodesically nearest valid pixels of ``src`` by Dijkstra with a binary heap.

    Args:
        src: flat index ``y * W + x`` of the source pixel.
        edges: (H, W) bool barriers.
        valid: (H, W) bool, pixels that may be neighbours.
        k: neighbours wanted.
        max_steps: search radius in steps.

    Returns:
        Up to k ``(flat index, a, b)`` in increasing distance ``a + b √2`` (a axis moves, b
        diagonal moves), ties by increasing flat index.
    """
    h, w = edges.shape
    limit = max_steps + 1e-9
    best: dict[int, float] = {src: 0.0}
    heap: list[tuple[float, int, int, int]] = [(0.0, src, 0, 0)]
    settled: set[int] = set()
    found: list[tuple[int, int, int]] = []
    while heap:
        _d, v, a, b = heapq.heappop(heap)     # (distance, flat index): ties by index
        if v in settled:
            continue
        settled.add(v)
        vy, vx = divmod(v, w)
        if valid[vy, vx]:
            found.append((v, a, b))
            if len(found) == k:
                break
        for dy, dx in MOVES:
            uy, ux = vy + dy, vx + dx
            if not (0 <= uy < h and 0 <= ux < w) or edges[uy, ux]:
                continue                       # outside, or entering an edge pixel
            diagonal = dy != 0 and dx != 0
            if diagonal and edges[vy, ux] and edges[uy, vx]:
                continue                       # cutting between two edge pixels
            na, nb = (a, b + 1) if diagonal else (a + 1, b)
            nd = na + nb * SQRT2               # same (a, b) -> same float, always
            u = uy * w + ux
            if nd > limit or u in settled or nd >= best.get(u, math.inf):
                continue
            best[u] = nd
            heapq.heappush(heap, (nd, u, na, nb))
    return found


def reference_geodesic_raw(range_mm: np.ndarray, edges: np.ndarray, *, k: int = 81,
                           sigma: float = 2.0, step: float = 1.0,
                           max_distance: float | None = None,
                           pixels: Sequence[tuple[int, int]] | None = None) -> np.ndarray:
    """Gaussian-weighted mean over the K geodesic neighbours (before edge snapping).

    Args:
        range_mm: (H, W) float R_F in mm, NaN = missing.
        edges: (H, W) bool edge map.
        k, sigma, step, max_distance: as :func:`tof_mpd_ros.correction.geodesic.geodesic_filter`.
        pixels: (y, x) pixels to compute; None = every pixel.

    Returns:
        (H, W) float64 filtered range; NaN at edge pixels, pixels not computed and pixels with
        no valid neighbour within reach.
    """
    h, w = range_mm.shape
    valid = np.isfinite(range_mm)
    max_steps = DEFAULT_MAX_STEPS if max_distance is None else max_distance / step
    out = np.full((h, w), np.nan)
    pts = [(y, x) for y in range(h) for x in range(w)] if pixels is None else pixels
    for y, x in pts:
        if edges[y, x]:
            continue                           # snapped afterwards
        num = den = 0.0
        for q, a, b in reference_knn(y * w + x, edges, valid, k, max_steps):
            d = (a + b * SQRT2) * step
            wgt = math.exp(-(d * d) / (2.0 * sigma * sigma))
            num += wgt * float(range_mm[q // w, q % w])
            den += wgt
        if den > 0:
            out[y, x] = num / den
    return out


def reference_snap(filtered: np.ndarray, range_mm: np.ndarray, edges: np.ndarray,
                   fill_missing: bool = True) -> np.ndarray:
    """Edge pixels take the filtered value of their most similar non-edge 8-neighbour.

    Most similar: closest to the pixel's own R_F, or the largest (farthest) value when its own
    R_F is missing; first in :data:`MOVES` order on ties; its own R_F if no neighbour has a
    value.

    Args:
        filtered: (H, W) float64 output of :func:`reference_geodesic_raw`.
        range_mm: (H, W) float R_F in mm, NaN = missing.
        edges: (H, W) bool.
        fill_missing: a missing edge pixel may take a value (else stays NaN).

    Returns:
        (H, W) float32.
    """
    h, w = filtered.shape
    out = filtered.astype(np.float32)
    for y, x in zip(*np.nonzero(edges), strict=True):
        own = float(range_mm[y, x])
        best, best_cost = None, math.inf
        for dy, dx in MOVES:
            ny, nx = y + dy, x + dx
            if not (0 <= ny < h and 0 <= nx < w) or edges[ny, nx]:
                continue
            side = filtered[ny, nx]
            if not np.isfinite(side):
                continue
            cost = abs(side - own) if math.isfinite(own) else -side
            if cost < best_cost:
                best, best_cost = side, cost
        value = own if best is None else best
        if not fill_missing and not math.isfinite(own):
            value = math.nan
        out[y, x] = value
    return out


def reference_geodesic_filter(range_mm: np.ndarray, edges: np.ndarray, *, k: int = 81,
                              sigma: float = 2.0, step: float = 1.0,
                              max_distance: float | None = None,
                              fill_missing: bool = True) -> np.ndarray:
    """Straightforward equivalent of
    :func:`tof_mpd_ros.correction.geodesic.geodesic_filter` (same arguments).

    Returns:
        (H, W) float32 filtered radial range in mm.
    """
    raw = reference_geodesic_raw(range_mm, edges, k=k, sigma=sigma, step=step,
                                 max_distance=max_distance)
    if not fill_missing:
        raw[~np.isfinite(range_mm)] = np.nan
    return reference_snap(raw, range_mm, edges, fill_missing)


# ---------------------------------------------------------------------------------------------
# the whole pipeline


def reference_correct(model: CorrectionModel, range_mm: np.ndarray, amplitude: np.ndarray, *,
                      use_range_net: bool = True, use_boundary: bool = True
                      ) -> CorrectionResult:
    """The straightforward equivalent of :func:`tof_mpd_ros.correction.pipeline.correct` for
    one (H, W) frame.

    Args:
        model: the correction model (CPU).
        range_mm: (H, W) raw radial range in mm; NaN/inf/<= 0 = invalid.
        amplitude: (H, W) raw amplitude; NaN/inf/<= 0 = invalid.
        use_range_net: apply F.
        use_boundary: apply G and the geodesic filter.

    Returns:
        A :class:`tof_mpd_ros.correction.pipeline.CorrectionResult` with (H, W) arrays.

    Raises:
        InputError: as :func:`tof_mpd_ros.correction.pipeline.check_frame_pair`; a batch is refused.
    """
    r, a = check_frame_pair(model.shape, range_mm, amplitude)
    if r.ndim != 2:
        raise InputError("reference_correct takes one (H, W) frame")
    h, w = r.shape
    calibrated = reference_calibration(model.calibration, r, a)
    feats, valid = reference_encode(calibrated, a, model.encoding)
    calib = np.where(valid, calibrated, np.float32(np.nan)).astype(np.float32)
    no_edges = np.zeros((h, w), bool)
    if not (use_range_net or use_boundary):
        return CorrectionResult(calib, no_edges, valid.astype(np.float32), calib, calib, valid)
    weights = ReferenceWeights.from_model(model)
    range_f = calib
    if use_range_net:
        range_f = (calib + reference_range_net(weights, feats).reshape(h, w)).astype(np.float32)
    if not use_boundary:
        return CorrectionResult(range_f, no_edges, valid.astype(np.float32), calib, range_f,
                                valid)
    probs = reference_boundary_nets(weights, feats)                      # (H*W, 4)
    scores = np.where(valid, probs.T.reshape(-1, h, w), np.float32(0.0)).astype(np.float32)
    confidence = np.where(valid, 1.0 - scores.max(axis=0), 0.0).astype(np.float32)
    g = model.geodesic
    edges, _ = edge_map_from_responses(scores, low=g.edge_low, high=g.edge_high)
    filtered = reference_geodesic_filter(range_f, edges, k=g.k, sigma=g.sigma, step=g.step)
    final = np.where(valid, filtered, np.float32(np.nan)).astype(np.float32)
    return CorrectionResult(final, edges, confidence, calib, range_f, valid)
