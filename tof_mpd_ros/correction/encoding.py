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

Both x terms lie in [-0.5, 0.5]. A pixel is *valid* when its range and amplitude are finite and
> 0. Invalid neighbours and neighbours outside the image contribute 0 (read as "same as the
centre"); rows of invalid centres are all zero and flagged in the returned mask. Feature layout:
``[x_R (M) | x_A (M) | b_R (n_bins) | b_A (n_bins)]``, 280 columns for the paper's numbers; the
boundary networks use the first ``2 M`` = 240.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

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
        range_patches: (N, P*P) float32 range in mm, row-major patch, NaN = invalid/outside.
        log_amp_patches: (N, P*P) float32 natural-log amplitude, NaN = invalid/outside.
        amplitude_centre: (N,) float32 linear amplitude of the centre pixel.
        config: encoding constants.
        boundary_only: return only ``[x_R x_A]`` (N, 2M) and skip the one-hot terms.

    Returns:
        (N, 2M + 2 n_bins) float32 features (or (N, 2M)); rows whose centre is NaN are zero.
    """
    p2 = config.patch_size ** 2
    c = p2 // 2
    n = range_patches.shape[0]
    width = config.n_boundary_features if boundary_only else config.n_features
    out = range_patches.new_zeros((n, width))
    m = config.n_neighbours
    _centred(range_patches, c, config.range_clip_mm, out[:, :m])
    _centred(log_amp_patches, c, config.amplitude_log_clip, out[:, m:2 * m])
    if not boundary_only:
        rc = range_patches[:, c]
        # The amplitude bin of an invalid centre must stay empty like its range bin.
        ac = torch.where(torch.isnan(rc), rc, amplitude_centre)
        _one_hot(rc, config.range_min_mm, config.range_max_mm, config.n_bins,
                 out[:, 2 * m:2 * m + config.n_bins])
        _one_hot(ac, config.amplitude_min, config.amplitude_max, config.n_bins,
                 out[:, 2 * m + config.n_bins:])
    return out


def f32(x: float) -> float:
    """``x`` rounded to float32, so torch and numpy float32 arithmetic use the same constant."""
    return float(np.float32(x))


def _centred(patches: torch.Tensor, c: int, clip: float, out: torch.Tensor) -> None:
    """Write clip(patch - centre, -clip, clip) / (2 clip) without the centre column into out."""
    diff = patches - patches[:, c:c + 1]
    # Multiply by the float32 reciprocal (what torch does for a scalar divide anyway).
    diff = diff.clamp_(-f32(clip), f32(clip)).mul_(f32(0.5 / f32(clip))).nan_to_num_(0.0)
    out[:, :c] = diff[:, :c]
    out[:, c:] = diff[:, c + 1:]


def _one_hot(values: torch.Tensor, lo: float, hi: float, n_bins: int, out: torch.Tensor) -> None:
    """Set out[i, bin(values[i])] = 1; NaN values set nothing."""
    pos = (values - f32(lo)) * f32(n_bins / (hi - lo))
    ok = ~torch.isnan(pos)
    idx = pos.nan_to_num(0.0).floor().clamp_(0, n_bins - 1).long()
    out.scatter_(1, idx[:, None], ok[:, None].to(out.dtype))


def frame_patches(plane: torch.Tensor, patch_size: int) -> torch.Tensor:
    """All P x P patches of a NaN-padded plane.

    Args:
        plane: (B, H, W) float32.
        patch_size: odd P.

    Returns:
        (B*H*W, P*P) float32, row-major over (b, y, x); outside-image entries are NaN.
    """
    half = patch_size // 2
    b, h, w = plane.shape
    padded = tnf.pad(plane[:, None], (half, half, half, half), value=float("nan"))[:, 0]
    windows = padded.unfold(1, patch_size, 1).unfold(2, patch_size, 1)  # (B, H, W, P, P)
    return windows.reshape(b * h * w, patch_size * patch_size)


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
    r = _as_tensor(range_mm, device)
    a = _as_tensor(amplitude, device)
    if r.shape != a.shape or r.ndim not in (2, 3):
        raise InputError(f"range_mm and amplitude must both be (H, W) or (B, H, W), got "
                         f"{tuple(r.shape)} and {tuple(a.shape)}")
    if r.ndim == 2:
        r, a = r[None], a[None]
    planes_r, planes_la, valid = prepare_planes(r, a)
    feats = encode_patches(frame_patches(planes_r, config.patch_size),
                           frame_patches(planes_la, config.patch_size),
                           a.reshape(-1), config, boundary_only=boundary_only)
    return feats, valid
