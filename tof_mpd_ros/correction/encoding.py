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

The division by 2D / 2L is a multiplication by its float32 reciprocal (bit-identical in torch and
numpy). Both x terms lie in [-0.5, 0.5]. A pixel is *valid* when its range and amplitude are
finite and > 0. Invalid neighbours and neighbours outside the image contribute 0 (read as "same
as the centre"); rows of invalid centres are all zero and flagged in the returned mask. Layout:
``[x_R (M) | x_A (M) | b_R (n_bins) | b_A (n_bins)]``, 280 columns for the paper's numbers; the
boundary networks use the first ``2 M`` = 240. :func:`encode_frame_columns` gives the same numbers
in the layout of the fused inference path (offsets as rows, centre row kept at 0, bins as
indices); training gathers patches of sampled pixels through the same :func:`encode_patches`.
The CPU fast path (``pipeline.correct``) uses :func:`frame_planes` and :func:`encode_rows`:
compiled kernels giving the same numbers bit for bit (float32 operations in the same order),
written into preallocated buffers a band of rows at a time.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numba
import numpy as np
import torch
import torch.nn.functional as tnf

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


def _as_tensor(x: np.ndarray | torch.Tensor, device: torch.device | str | None) -> torch.Tensor:
    t = x if isinstance(x, torch.Tensor) else torch.from_numpy(np.asarray(x))
    return t.to(device=device if device is not None else t.device, dtype=torch.float32)


def prepare_planes(range_mm: torch.Tensor, amplitude: torch.Tensor
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per-pixel planes the patches are cut from.

    Args:
        range_mm: (B, H, W) float32 radial range in mm.
        amplitude: (B, H, W) float32 amplitude.

    Returns:
        ``(range, log_amplitude, valid)``: (B, H, W) float32 range in mm and natural-log
        amplitude, both NaN where invalid, and the (B, H, W) bool validity mask.
    """
    valid = torch.isfinite(range_mm) & torch.isfinite(amplitude) & (range_mm > 0) & (amplitude > 0)
    nan = torch.tensor(float("nan"), dtype=torch.float32, device=range_mm.device)
    r = torch.where(valid, range_mm, nan)
    # Log in float64 then round: the result is the correctly rounded float32 log in practice,
    # independent of the float32 log implementation (numpy and torch differ in the last bit).
    log_a = torch.where(valid, amplitude, nan).double().log().float()
    return r, log_a, valid


def encode_patches(
    range_patches: torch.Tensor,
    log_amp_patches: torch.Tensor,
    amplitude_centre: torch.Tensor,
    config: EncodingConfig,
    *,
    boundary_only: bool = False,
) -> torch.Tensor:
    """Encode pixels from their patches (shared by whole-frame inference and training).

    Args:
        range_patches: (N, P*P) float32 range in mm, row-major patch, NaN = invalid/outside;
            or a (..., P, P) window view whose leading dims flatten to N (no copy is made).
        log_amp_patches: same layout, natural-log amplitude.
        amplitude_centre: (N,) float32 linear amplitude of the centre pixels.
        config: encoding constants.
        boundary_only: return only ``[x_R x_A]`` (N, 2M) and skip the one-hot terms.

    Returns:
        (N, 2M + 2 n_bins) float32 features (or (N, 2M)); rows whose centre is NaN are zero.
    """
    m = config.n_neighbours
    p = config.patch_size
    rp = range_patches.reshape(-1, p, p) if range_patches.ndim == 2 else range_patches
    lp = log_amp_patches.reshape(-1, p, p) if log_amp_patches.ndim == 2 else log_amp_patches
    rc = rp[..., p // 2, p // 2].reshape(-1)
    n = rc.shape[0]
    width = config.n_boundary_features if boundary_only else config.n_features
    out = rp.new_empty((n, width))      # every column is written below
    _centred(rp, config.range_clip_mm, out[:, :m])
    _centred(lp, config.amplitude_log_clip, out[:, m:2 * m])
    if not boundary_only:
        nb = config.n_bins
        out[:, 2 * m:].zero_()
        ok = ~torch.isnan(rc)          # an invalid centre gets no bin at all
        ones = ok[:, None].to(out.dtype)
        out[:, 2 * m:2 * m + nb].scatter_(
            1, centre_bins(rc, config.range_min_mm, config.range_max_mm, nb)[:, None], ones)
        out[:, 2 * m + nb:].scatter_(
            1, centre_bins(amplitude_centre, config.amplitude_min, config.amplitude_max,
                           nb)[:, None], ones)
    return out


def f32(x: float) -> float:
    """``x`` rounded to float32, so torch and numpy float32 arithmetic use the same constant."""
    return float(np.float32(x))


def _centred(patches: torch.Tensor, clip: float, out: torch.Tensor) -> None:
    """Write clip(patch - centre, -clip, clip) / (2 clip) without the centre column into out.

    Args:
        patches: (..., P, P) (any strides), leading dims flattening to N.
        clip: saturation of the difference.
        out: (N, P*P - 1) destination view.
    """
    p = patches.shape[-1]
    c = p * p // 2
    # Explicit contiguous output: subtracting from a window view would inherit its odd strides.
    diff = patches.new_empty(patches.shape)
    torch.sub(patches, patches[..., p // 2, p // 2, None, None], out=diff)
    diff = diff.view(-1, p * p)
    # Multiply by the float32 reciprocal (what torch does for a scalar divide anyway).
    diff = diff.clamp_(-f32(clip), f32(clip)).mul_(f32(0.5 / f32(clip))).nan_to_num_(0.0)
    out[:, :c] = diff[:, :c]
    out[:, c:] = diff[:, c + 1:]


def centre_bins(values: torch.Tensor, lo: float, hi: float, n_bins: int) -> torch.Tensor:
    """Uniform quantisation of ``values`` into ``n_bins`` intervals over [lo, hi).

    Args:
        values: (N,) float32.
        lo, hi: interval; values outside fall into the first / last bin.
        n_bins: number of intervals.

    Returns:
        (N,) int64 bin index in [0, n_bins); NaN maps to 0 (callers mask invalid pixels).
    """
    pos = (values - f32(lo)) * f32(n_bins / (hi - lo))
    return pos.nan_to_num_(0.0).floor_().clamp_(0, n_bins - 1).long()


def frame_windows(plane: torch.Tensor, patch_size: int) -> torch.Tensor:
    """All P x P patches of a plane, as a view of its NaN-padded copy.

    Args:
        plane: (B, H, W) float32.
        patch_size: odd P.

    Returns:
        (B, H, W, P, P) float32 view; outside-image entries are NaN.
    """
    half = patch_size // 2
    padded = tnf.pad(plane[:, None], (half, half, half, half), value=float("nan"))[:, 0]
    return padded.unfold(1, patch_size, 1).unfold(2, patch_size, 1)


def _checked_pair(range_mm: np.ndarray | torch.Tensor, amplitude: np.ndarray | torch.Tensor,
                  device: torch.device | str | None) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, H, W) float32 tensors of a (H, W) or (B, H, W) pair."""
    r = _as_tensor(range_mm, device)
    a = _as_tensor(amplitude, device)
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
    """Encode every pixel of one frame or a batch of frames at once (no per-pixel loop).

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
    r, a = _checked_pair(range_mm, amplitude, device)
    planes_r, planes_la, valid = prepare_planes(r, a)
    feats = encode_patches(frame_windows(planes_r, config.patch_size),
                           frame_windows(planes_la, config.patch_size),
                           a.reshape(-1), config, boundary_only=boundary_only)
    return feats, valid


@dataclass
class ColumnEncoding:
    """One frame's encoding in the column layout of the fused inference path.

    The same numbers as :func:`encode_frame`, laid out for GEMMs without copies: patch offsets
    are rows (the centre row is kept and is always 0, so the networks' first layers get a zero
    weight there) and pixels are columns; the one-hot terms are given as bin indices.

    Attributes:
        x_range: (P*P, H*W) float32 x_R rows, centre row included.
        x_amplitude: (P*P, H*W) float32 x_A rows, centre row included.
        bin_range: (H*W,) int64 b_R bin index.
        bin_amplitude: (H*W,) int64 b_A bin index.
        valid: (H, W) bool validity of each centre pixel (rows of invalid pixels are zero,
            their bins 0).
    """

    x_range: torch.Tensor
    x_amplitude: torch.Tensor
    bin_range: torch.Tensor
    bin_amplitude: torch.Tensor
    valid: torch.Tensor


def _centred_columns(plane: torch.Tensor, patch_size: int, clip: float) -> torch.Tensor:
    """(P*P, H*W) clip(q - p, -clip, clip) / (2 clip) of a NaN-marked (H, W) plane, NaN -> 0."""
    half = patch_size // 2
    padded = tnf.pad(plane[None, None], (half, half, half, half), value=float("nan"))
    cols = tnf.unfold(padded, patch_size)[0]                 # (P*P, H*W), im2col
    cols.sub_(plane.reshape(1, -1))
    return cols.clamp_(-f32(clip), f32(clip)).mul_(f32(0.5 / f32(clip))).nan_to_num_(0.0)


def encode_frame_columns(range_mm: np.ndarray | torch.Tensor,
                         amplitude: np.ndarray | torch.Tensor, config: EncodingConfig, *,
                         device: torch.device | str | None = None) -> list[ColumnEncoding]:
    """Encode every pixel of one or B frames in the column layout (see :class:`ColumnEncoding`).

    Args:
        range_mm: (H, W) or (B, H, W) float calibrated radial range in mm, NaN = invalid.
        amplitude: same shape, amplitude, NaN = invalid.
        config: encoding constants.
        device: torch device of the result.

    Returns:
        One :class:`ColumnEncoding` per frame.
    """
    r, a = _checked_pair(range_mm, amplitude, device)
    planes_r, planes_la, valid = prepare_planes(r, a)
    out = []
    for i in range(r.shape[0]):
        rc = planes_r[i].reshape(-1)
        ac = torch.where(torch.isnan(rc), rc, a[i].reshape(-1))   # invalid centre -> bin 0
        out.append(ColumnEncoding(
            _centred_columns(planes_r[i], config.patch_size, config.range_clip_mm),
            _centred_columns(planes_la[i], config.patch_size, config.amplitude_log_clip),
            centre_bins(rc, config.range_min_mm, config.range_max_mm, config.n_bins),
            centre_bins(ac, config.amplitude_min, config.amplitude_max, config.n_bins),
            valid[i]))
    return out


# ---------------------------------------------------------------------------------------------
# Compiled kernels of the CPU fast path (same float32 operations as the torch code above).


def plane_constants(config: EncodingConfig) -> np.ndarray:
    """(8,) float32 constants of :func:`frame_planes` / :func:`encode_rows`.

    ``[D, 0.5 / D, L, 0.5 / L, range_min, n_bins / range span, amplitude_min,
    n_bins / amplitude span]``, each rounded to float32 exactly as the torch code rounds them.
    """
    d, lc = f32(config.range_clip_mm), f32(config.amplitude_log_clip)
    nb = config.n_bins
    return np.array([d, f32(0.5 / d), lc, f32(0.5 / lc), f32(config.range_min_mm),
                     f32(nb / (config.range_max_mm - config.range_min_mm)),
                     f32(config.amplitude_min),
                     f32(nb / (config.amplitude_max - config.amplitude_min))], np.float32)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _bin(value: float, lo: float, scale: float, n_bins: int) -> int:  # pragma: no cover
    pos = (value - lo) * scale                    # float32 arithmetic, as centre_bins
    if pos != pos:
        return 0
    return int(min(max(np.floor(pos), 0.0), n_bins - 1.0))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def frame_planes(calibrated: np.ndarray, amplitude: np.ndarray, consts: np.ndarray,
                 n_bins: int, r_pad: np.ndarray, la_pad: np.ndarray, bin_range: np.ndarray,
                 bin_amplitude: np.ndarray, valid: np.ndarray) -> None:  # pragma: no cover
    """Fill the per-frame planes of the fast path (see :func:`prepare_planes`, :func:`centre_bins`).

    Args:
        calibrated: (H, W) float32 calibrated range in mm.
        amplitude: (H, W) float32 amplitude.
        consts: :func:`plane_constants`.
        n_bins: one-hot width.
        r_pad, la_pad: (H + P - 1, W + P - 1) float32 outputs, range and log amplitude at
            offset P // 2, NaN where invalid; the border must already hold NaN.
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


@numba.njit(cache=True, nogil=True, error_model="numpy")
def encode_rows(r_pad: np.ndarray, la_pad: np.ndarray, y0: int, y1: int, patch_size: int,
                consts: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover
    """``[x_R x_A]`` of the pixels of rows [y0, y1), pixel-major, into ``out``.

    The same float32 numbers as :func:`encode_patches` (``boundary_only=True``): difference,
    clip, multiplication by the float32 reciprocal, NaN -> 0.

    Args:
        r_pad, la_pad: planes from :func:`frame_planes`.
        y0, y1: row band.
        patch_size: P.
        consts: :func:`plane_constants`.
        out: (>= (y1 - y0) * W, 2 M) float32, row ``(y - y0) * W + x`` for pixel (y, x).
    """
    p = patch_size
    w = r_pad.shape[1] - p + 1
    half = p // 2
    m = p * p - 1
    clip_r, scale_r, clip_a, scale_a = consts[0], consts[1], consts[2], consts[3]
    zero = np.float32(0.0)
    i = 0
    for y in range(y0, y1):
        for col in range(w):
            row = out[i]
            rc = r_pad[y + half, col + half]
            ac = la_pad[y + half, col + half]
            o = 0
            for dy in range(p):
                rs = r_pad[y + dy, col:col + p]
                als = la_pad[y + dy, col:col + p]
                for dx in range(p):
                    if dy == half and dx == half:
                        continue
                    d = min(max(rs[dx] - rc, -clip_r), clip_r) * scale_r
                    row[o] = d if d == d else zero
                    e = min(max(als[dx] - ac, -clip_a), clip_a) * scale_a
                    row[m + o] = e if e == e else zero
                    o += 1
            i += 1
