"""Patch encoding of the networks' input (paper eq. 3): ``[x_R x_A b_R b_A]`` per pixel.

For a pixel ``p`` with an ``P x P`` patch (P = 11) and ``M = P * P - 1`` neighbours ``q``
(row-major patch order, centre dropped):

* ``x_R[q] = clip(R(q) - R(p), -D, D) / (2 D)`` with ``D = range_clip_mm`` (default 50 mm):
  range differences in mm, saturated at +-D so a depth discontinuity reads as +-0.5;
* ``x_A[q] = clip(ln A(q) - ln A(p), -L, L) / (2 L)`` with ``L = amplitude_log_clip`` (default
  ln 4): the same operation on *log* amplitude, which makes x_A independent of the sensor's
  amplitude unit and of the inverse-square falloff common to the patch;
* ``b_R`` / ``b_A``: one-hot of R(p) / A(p) uniformly quantised into ``n_bins`` intervals over
  ``[range_min_mm, range_max_mm)`` / ``[amplitude_min, amplitude_max)``; values outside fall in the
  first / last bin.

The division by 2D / 2L is a multiplication by its float32 reciprocal; the log amplitude is
computed in float64 and rounded to float32. Both x terms lie in [-0.5, 0.5]. A pixel is *valid*
when its range and amplitude are finite and > 0. Invalid neighbours and neighbours outside the
image contribute 0 (read as "same as the centre"); rows of invalid centres are all zero and
flagged in the returned mask. Layout: ``[x_R (M) | x_A (M) | b_R (n_bins) | b_A (n_bins)]``, 280
columns for the paper's numbers; the boundary networks use the first ``2 M`` = 240.

This module is the package's one implementation of the encoding, in three compiled kernels:
:func:`frame_planes` (validity, the NaN-padded range and log-amplitude planes and the bin
indices of a frame), :func:`_term` (one x term) and :func:`_bin` (one quantisation). Every user
goes through them: the correction's fast path a band of rows at a time, feature-major, into
preallocated buffers (:func:`encode_band`), whole frames as torch tensors
(:func:`encode_frame`), and training's sampled pixels of many frames (:func:`padded_planes`
once, then :func:`encode_pixels` per batch, a pixel's row at a time through
:func:`_encode_pixel`), so training and inference see bit-identical features.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import NamedTuple

import numba
import numpy as np
import torch

from ..errors import InputError


@dataclass(frozen=True)
class EncodingConfig:
    """Constants of the patch encoding (stored in the weights file).

    Attributes:
        patch_size: odd patch side P in pixels (paper: 11).
        n_bins: intervals of the one-hot centre encodings (paper: 20).
        range_clip_mm: D, range differences saturate at +-D mm.
        amplitude_log_clip: L, log-amplitude differences saturate at +-L (natural log).
        range_min_mm, range_max_mm: range interval quantised by b_R, mm.
        amplitude_min, amplitude_max: amplitude interval quantised by b_A, sensor units.
    """

    patch_size: int = 11
    n_bins: int = 20
    range_clip_mm: float = 50.0
    amplitude_log_clip: float = math.log(4.0)
    range_min_mm: float = 100.0
    range_max_mm: float = 700.0
    amplitude_min: float = 0.0
    amplitude_max: float = 1.0

    def __post_init__(self) -> None:
        if self.patch_size < 3 or self.patch_size % 2 == 0:
            raise InputError(f"patch_size must be odd and >= 3, got {self.patch_size}")
        if self.n_bins < 1:
            raise InputError(f"n_bins must be >= 1, got {self.n_bins}")
        if not (self.range_clip_mm > 0 and self.amplitude_log_clip > 0):
            raise InputError("range_clip_mm and amplitude_log_clip must be > 0, got "
                             f"{self.range_clip_mm}, {self.amplitude_log_clip}")
        if not (self.range_max_mm > self.range_min_mm
                and self.amplitude_max > self.amplitude_min):
            raise InputError("bin intervals must have max > min, got range "
                             f"[{self.range_min_mm}, {self.range_max_mm}), amplitude "
                             f"[{self.amplitude_min}, {self.amplitude_max})")

    @property
    def n_neighbours(self) -> int:
        """M = P * P - 1, the length of x_R and of x_A."""
        return self.patch_size ** 2 - 1

    @property
    def n_boundary_features(self) -> int:
        """Width of ``[x_R x_A]``, the boundary networks' input (240)."""
        return 2 * self.n_neighbours

    @property
    def n_features(self) -> int:
        """Width of ``[x_R x_A b_R b_A]``, the range network's input (280)."""
        return 2 * self.n_neighbours + 2 * self.n_bins

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


def f32(x: float) -> float:
    """``x`` rounded to float32, so every float32 constant is rounded once, the same way."""
    return float(np.float32(x))


def plane_constants(config: EncodingConfig) -> np.ndarray:
    """(8,) float32 constants of the kernels.

    ``[D, 0.5 / D, L, 0.5 / L, range_min, n_bins / range span, amplitude_min,
    n_bins / amplitude span]``, each rounded to float32 once.
    """
    d, lc = f32(config.range_clip_mm), f32(config.amplitude_log_clip)
    nb = config.n_bins
    return np.array([d, f32(0.5 / d), lc, f32(0.5 / lc), f32(config.range_min_mm),
                     f32(nb / (config.range_max_mm - config.range_min_mm)),
                     f32(config.amplitude_min),
                     f32(nb / (config.amplitude_max - config.amplitude_min))], np.float32)


# ---------------------------------------------------------------------------------------------
# The compiled kernels (float32 arithmetic throughout).


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _bin(value: float, lo: float, scale: float, n_bins: int) -> int:  # pragma: no cover
    """The package's one quantisation of a centre value: ``floor((value - lo) * scale)``
    clamped to ``[0, n_bins)`` in float32 arithmetic; NaN maps to bin 0."""
    pos = (value - lo) * scale
    if pos != pos:
        return 0
    return int(min(max(np.floor(pos), 0.0), n_bins - 1.0))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def frame_planes(calibrated: np.ndarray, amplitude: np.ndarray, consts: np.ndarray,
                 n_bins: int, r_pad: np.ndarray, la_pad: np.ndarray, bin_range: np.ndarray,
                 bin_amplitude: np.ndarray, valid: np.ndarray) -> None:  # pragma: no cover
    """The package's one computation of a frame's validity, padded planes and bins.

    Args:
        calibrated: (H, W) float32 calibrated range in mm.
        amplitude: (H, W) float32 amplitude.
        consts: :func:`plane_constants`.
        n_bins: one-hot width.
        r_pad, la_pad: (H + P - 1, W + P - 1) float32 outputs, range in mm and natural-log
            amplitude (float64 log rounded to float32) at offset P // 2, NaN where invalid;
            the border must already hold NaN.
        bin_range, bin_amplitude: (H * W,) int32 outputs, bin index (0 for invalid pixels).
        valid: (H, W) bool output.
    """
    h, w = calibrated.shape
    half = (r_pad.shape[0] - h) // 2
    nan = np.float32(np.nan)
    for y in range(h):
        for x in range(w):
            r = calibrated[y, x]
            a = amplitude[y, x]
            ok = np.isfinite(r) and np.isfinite(a) and r > 0 and a > 0
            valid[y, x] = ok
            i = y * w + x
            if ok:
                r_pad[y + half, x + half] = r
                la_pad[y + half, x + half] = np.float32(math.log(np.float64(a)))
                bin_range[i] = _bin(r, consts[4], consts[5], n_bins)
                bin_amplitude[i] = _bin(a, consts[6], consts[7], n_bins)
            else:
                r_pad[y + half, x + half] = nan
                la_pad[y + half, x + half] = nan
                bin_range[i] = 0
                bin_amplitude[i] = 0


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _term(value: float, centre: float, clip: float, scale: float) -> float:  # pragma: no cover
    """The package's one x term: the difference clipped to ``[-clip, clip]``, times the float32
    reciprocal ``scale``; NaN (an invalid neighbour or centre) -> 0."""
    d = min(max(value - centre, -clip), clip) * scale
    return d if d == d else np.float32(0.0)


# Inlined into its callers (numba IR): a call per pixel costs ~6 % of the fast path's encoding.
@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _encode_pixel(r_pad: np.ndarray, la_pad: np.ndarray, y: int, x: int, patch_size: int,
                  consts: np.ndarray, row: np.ndarray) -> None:  # pragma: no cover
    """The package's one implementation of ``[x_R x_A]``: pixel (y, x) into ``row[:2 M]``.

    Args:
        r_pad, la_pad: (H + P - 1, W + P - 1) planes of :func:`frame_planes`; the pixel's
            patch is ``[y, y + P) x [x, x + P)``.
        y, x: pixel (image coordinates).
        patch_size: P.
        consts: :func:`plane_constants`.
        row: (>= 2 M,) float32 output: difference, clip, multiplication by the float32
            reciprocal, NaN -> 0 (an invalid centre gives a row of zeros).
    """
    p = patch_size
    half = p // 2
    m = p * p - 1
    clip_r, scale_r, clip_a, scale_a = consts[0], consts[1], consts[2], consts[3]
    rc = r_pad[y + half, x + half]
    ac = la_pad[y + half, x + half]
    o = 0
    for dy in range(p):
        rs = r_pad[y + dy, x:x + p]
        als = la_pad[y + dy, x:x + p]
        for dx in range(p):
            if dy == half and dx == half:
                continue
            row[o] = _term(rs[dx], rc, clip_r, scale_r)
            row[m + o] = _term(als[dx], ac, clip_a, scale_a)
            o += 1


@numba.njit(cache=True, nogil=True, error_model="numpy")
def encode_band(r_pad: np.ndarray, la_pad: np.ndarray, y0: int, y1: int, patch_size: int,
                consts: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover
    """``[x_R x_A]`` of the pixels of rows [y0, y1), feature-major, into ``out`` (the
    correction's fast path).

    Feature-major because then each feature of a row of pixels is one contiguous loop over
    contiguous planes, which the compiler vectorises; pixel-major rows cost 5.7x as much
    (measured at 320x240, one thread: 13.6 against 2.4 ms per frame). The first layers' GEMM
    takes either layout.

    Args:
        r_pad, la_pad: planes from :func:`frame_planes`.
        y0, y1: row band.
        patch_size: P.
        consts: :func:`plane_constants`.
        out: (2 M, (y1 - y0) * W) float32, column ``(y - y0) * W + x`` for pixel (y, x).
    """
    _encode_band(r_pad, la_pad, y0, y1, patch_size, consts, out, False)


# The int8 inputs of ``precision="int8"``: every x term lies in [-0.5, 0.5], so one fixed scale
# maps it onto the symmetric int8 range with no clipping and keeps 0 (an invalid or equal
# neighbour) exactly 0; no per-frame calibration of the scale is needed. A step is 1/254 of x:
# 0.39 mm of range difference, 0.55 % of amplitude ratio.
INT8_SCALE = 254.0


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _quantize(x: float) -> int:  # pragma: no cover
    """The package's one quantisation of an x term: ``rint(INT8_SCALE * x)`` (float32 product,
    half to even). No clamp (it cost a third of the int8 encoding): |x| <= 0.5 to a float32
    ulp gives |q| <= 127."""
    return np.int8(np.rint(x * np.float32(INT8_SCALE)))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def quantize_rows(x: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover
    """:func:`_quantize` of every element of ``x`` (see ``INT8_SCALE``).

    Args:
        x: (n, k) float32 in [-0.5, 0.5] (the encoding's range; not checked here).
        out: (n, k) int8 output.
    """
    for i in range(x.shape[0]):
        for j in range(x.shape[1]):
            out[i, j] = _quantize(x[i, j])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def encode_band_int8(r_pad: np.ndarray, la_pad: np.ndarray, y0: int, y1: int,
                     patch_size: int, consts: np.ndarray,
                     out: np.ndarray) -> None:  # pragma: no cover
    """:func:`encode_band` quantised as :func:`quantize_rows` does, written as int8 (a
    quarter of the bytes).

    Args:
        r_pad, la_pad, y0, y1, patch_size, consts: as :func:`encode_band`.
        out: (2 M, (y1 - y0) * W) int8, column ``(y - y0) * W + x`` for pixel (y, x).
    """
    _encode_band(r_pad, la_pad, y0, y1, patch_size, consts, out, True)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _encode_band(r_pad: np.ndarray, la_pad: np.ndarray, y0: int, y1: int, patch_size: int,
                 consts: np.ndarray, out: np.ndarray,
                 quantised: bool) -> None:  # pragma: no cover
    """:func:`encode_band` (float32 ``out``) or :func:`encode_band_int8` (``quantised``, int8
    ``out``): feature k = neighbour (dy, dx), row-major patch order, centre dropped."""
    p = patch_size
    half = p // 2
    m = p * p - 1
    w = r_pad.shape[1] - p + 1
    clip_r, scale_r, clip_a, scale_a = consts[0], consts[1], consts[2], consts[3]
    k = 0
    for dy in range(p):
        for dx in range(p):
            if dy == half and dx == half:
                continue
            for y in range(y0, y1):
                i0 = (y - y0) * w
                rs = r_pad[y + dy, dx:dx + w]
                rc = r_pad[y + half, half:half + w]
                als = la_pad[y + dy, dx:dx + w]
                ac = la_pad[y + half, half:half + w]
                o_r = out[k, i0:i0 + w]
                o_a = out[m + k, i0:i0 + w]
                for x in range(w):
                    d = _term(rs[x], rc[x], clip_r, scale_r)
                    e = _term(als[x], ac[x], clip_a, scale_a)
                    if quantised:
                        o_r[x] = _quantize(d)
                        o_a[x] = _quantize(e)
                    else:
                        o_r[x] = d
                        o_a[x] = e
            k += 1


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _encode_at(r_pads: np.ndarray, la_pads: np.ndarray, amplitude: np.ndarray,
               flat_index: np.ndarray, patch_size: int, consts: np.ndarray, n_bins: int,
               out: np.ndarray) -> None:  # pragma: no cover
    """Rows of the pixels ``flat_index`` of a stack of frames (see :func:`encode_pixels`)."""
    _n, h, w = amplitude.shape
    m = patch_size * patch_size - 1
    half = patch_size // 2
    with_bins = out.shape[1] > 2 * m
    for i in range(flat_index.shape[0]):
        q = flat_index[i]
        f = q // (h * w)
        y = (q - f * h * w) // w
        x = q - f * h * w - y * w
        row = out[i]
        row[:] = 0.0
        rc = r_pads[f, y + half, x + half]
        if rc != rc:                         # invalid centre: a row of zeros, no bin
            continue
        _encode_pixel(r_pads[f], la_pads[f], y, x, patch_size, consts, row)
        if with_bins:
            row[2 * m + _bin(rc, consts[4], consts[5], n_bins)] = 1.0
            row[2 * m + n_bins + _bin(amplitude[f, y, x], consts[6], consts[7], n_bins)] = 1.0


# ---------------------------------------------------------------------------------------------
# Wrappers


class PaddedPlanes(NamedTuple):
    """:func:`frame_planes` of a stack of B frames.

    Attributes:
        range_mm: (B, H + P - 1, W + P - 1) float32 calibrated range in mm, NaN-padded, NaN
            where invalid.
        log_amplitude: same shape, float32 natural-log amplitude.
        amplitude: (B, H, W) float32 linear amplitude (for b_A).
        bin_range, bin_amplitude: (B, H * W) int32 bin indices (0 for invalid pixels).
        valid: (B, H, W) bool.
    """

    range_mm: np.ndarray
    log_amplitude: np.ndarray
    amplitude: np.ndarray
    bin_range: np.ndarray
    bin_amplitude: np.ndarray
    valid: np.ndarray


def padded_planes(calibrated: np.ndarray, amplitude: np.ndarray,
                  config: EncodingConfig) -> PaddedPlanes:
    """:func:`frame_planes` of every frame of a (B, H, W) stack.

    Args:
        calibrated: (B, H, W) float calibrated radial range in mm, NaN = invalid.
        amplitude: (B, H, W) float amplitude.
        config: encoding constants.
    """
    r = np.ascontiguousarray(calibrated, np.float32)
    a = np.ascontiguousarray(amplitude, np.float32)
    b, h, w = r.shape
    pad = config.patch_size - 1
    planes = PaddedPlanes(np.full((b, h + pad, w + pad), np.nan, np.float32),
                          np.full((b, h + pad, w + pad), np.nan, np.float32), a,
                          np.zeros((b, h * w), np.int32), np.zeros((b, h * w), np.int32),
                          np.zeros((b, h, w), bool))
    consts = plane_constants(config)
    for i in range(b):
        frame_planes(r[i], a[i], consts, config.n_bins, planes.range_mm[i],
                     planes.log_amplitude[i], planes.bin_range[i], planes.bin_amplitude[i],
                     planes.valid[i])
    return planes


def encode_pixels(range_planes: np.ndarray, log_amp_planes: np.ndarray, amplitude: np.ndarray,
                  flat_index: np.ndarray, config: EncodingConfig, *,
                  boundary_only: bool = False, out: np.ndarray | None = None) -> np.ndarray:
    """Encode chosen pixels of a stack of frames from their padded planes.

    Args:
        range_planes, log_amp_planes: (B, H + P - 1, W + P - 1) float32, as
            :class:`PaddedPlanes` (C-contiguous).
        amplitude: (B, H, W) float32 linear amplitude.
        flat_index: (N,) int flat indices into (B, H, W).
        config: encoding constants.
        boundary_only: only the ``[x_R x_A]`` columns (N, 2 M).
        out: optional C-contiguous float32 array of at least N rows of that width, written in
            its first N rows (the rest untouched) and returned whole.

    Returns:
        (N, 2 M + 2 n_bins) float32 features (or (N, 2 M)); rows of invalid centres are zero.
    """
    width = config.n_boundary_features if boundary_only else config.n_features
    if out is None:
        out = np.empty((len(flat_index), width), np.float32)
    elif (out.dtype != np.float32 or out.ndim != 2 or out.shape[1] != width
          or out.shape[0] < len(flat_index) or not out.flags.c_contiguous):
        raise InputError(f"out must be C-contiguous float32 (>= {len(flat_index)}, {width}), "
                         f"got {out.dtype} {out.shape}")
    _encode_at(range_planes, log_amp_planes, amplitude, np.asarray(flat_index, np.int64),
               config.patch_size, plane_constants(config), config.n_bins, out)
    return out


def _checked_pair(range_mm: np.ndarray | torch.Tensor, amplitude: np.ndarray | torch.Tensor
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(B, H, W) float32 arrays of a (H, W) or (B, H, W) pair (numpy or torch)."""
    r, a = (np.asarray(x.detach().cpu() if isinstance(x, torch.Tensor) else x, np.float32)
            for x in (range_mm, amplitude))
    if r.shape != a.shape or r.ndim not in (2, 3):
        raise InputError(f"range_mm and amplitude must both be (H, W) or (B, H, W), got "
                         f"{tuple(r.shape)} and {tuple(a.shape)}")
    return (r[None], a[None]) if r.ndim == 2 else (r, a)


def encode_frame(
    range_mm: np.ndarray | torch.Tensor,
    amplitude: np.ndarray | torch.Tensor,
    config: EncodingConfig,
    *,
    device: torch.device | str | None = None,
    boundary_only: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Encode every pixel of one frame or a batch of frames at once.

    Args:
        range_mm: (H, W) or (B, H, W) float radial range in mm (calibrated), NaN = invalid.
        amplitude: same shape, amplitude in sensor units, NaN = invalid.
        config: encoding constants.
        device: torch device for the result (default: the input's, CPU for numpy input).
        boundary_only: only ``[x_R x_A]`` columns.

    Returns:
        ``(features, valid)``: (B*H*W, n_features) float32 (rows in (b, y, x) order; a 2-D
        input counts as B = 1) and (B, H, W) bool validity of each centre pixel.

    Raises:
        InputError: shapes differ or are not 2-D/3-D.
    """
    if device is None:
        device = range_mm.device if isinstance(range_mm, torch.Tensor) else "cpu"
    r, a = _checked_pair(range_mm, amplitude)
    planes = padded_planes(r, a, config)
    feats = encode_pixels(planes.range_mm, planes.log_amplitude, planes.amplitude,
                          np.arange(r.size), config, boundary_only=boundary_only)
    return torch.from_numpy(feats).to(device), torch.from_numpy(planes.valid).to(device)
