"""``pixel_offset``: per-pixel range offset and gain (fixed-pattern error).

    r' = o_p + (1 + g_p) · r       o_p ~ N(offset_mean, offset_std²),  g_p ~ N(0, gain_std²)

The pattern is drawn from ``seed`` (stored in the config, independent of the frame's rng) and is
a function of the pixel's position relative to the principal point, not of the image size: a
crop of the sensor (the 180x140 frame, or the cell's window with its margin) carries the same
offsets at the same sensor pixels, so a frame rendered from its reference and the frame the cell
recorded agree. Exactly what the per-pixel linear calibration removes.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ....camera import Intrinsics
from ..context import RenderContext
from ..effect import Effect, param

_MASK64 = np.uint64(0xFFFFFFFFFFFFFFFF)


def _splitmix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64 finaliser: a well-mixed uint64 hash of each uint64 (wrapping arithmetic)."""
    x = (x + np.uint64(0x9E3779B97F4A7C15)) & _MASK64
    x = ((x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)) & _MASK64
    x = ((x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)) & _MASK64
    return x ^ (x >> np.uint64(31))


def _uniform(seed: int, stream: int, key: np.ndarray) -> np.ndarray:
    """Uniform (0, 1) numbers, one per uint64 ``key``, reproducible per (seed, stream)."""
    salt = _splitmix64(np.array([(int(seed) % 2**60) * 4 + stream], dtype=np.uint64))[0]
    bits = _splitmix64(key ^ salt) >> np.uint64(11)  # 53 random bits
    return (bits.astype(np.float64) + 0.5) / float(2**53)


def sensor_keys(intrinsics: Intrinsics) -> np.ndarray:
    """(H, W) uint64 key of each pixel from its half-pixel offset to the principal point."""
    v, u = np.mgrid[0:intrinsics.height, 0:intrinsics.width].astype(np.float64)
    du = np.rint(2.0 * (u - intrinsics.cx)).astype(np.int64) + 2**20
    dv = np.rint(2.0 * (v - intrinsics.cy)).astype(np.int64) + 2**20
    return (dv.astype(np.uint64) << np.uint64(32)) | du.astype(np.uint64)


@functools.lru_cache(maxsize=16)
def _unit_normals(intrinsics: Intrinsics, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Two independent (H, W) standard-normal fields (Box–Muller), cached per camera and seed:
    every frame of a camera draws the same pattern, and fitting re-renders many frames."""
    key = sensor_keys(intrinsics)
    u1, u2 = (_uniform(seed, s, key) for s in range(2))
    radius = np.sqrt(-2.0 * np.log(u1))
    fields = (radius * np.cos(2.0 * np.pi * u2), radius * np.sin(2.0 * np.pi * u2))
    for field in fields:
        field.setflags(write=False)  # shared by every caller
    return fields


def offset_pattern(intrinsics: Intrinsics, seed: int, offset_mean_mm: float,
                   offset_std_mm: float, gain_std: float) -> tuple[np.ndarray, np.ndarray]:
    """The fixed pattern of the pixels of an image with ``intrinsics``.

    Returns:
        (H, W) float64 offsets in mm and (H, W) float64 gains (unitless); a pixel at the same
        offset from the principal point gets the same values in any crop.
    """
    n_offset, n_gain = _unit_normals(intrinsics, int(seed))
    return offset_mean_mm + offset_std_mm * n_offset, gain_std * n_gain


@dataclass(frozen=True)
class PixelOffsetParams:
    """Parameters of :class:`PixelOffset`."""

    offset_mean_mm: float = param(4.0, -20.0, 20.0, "mm", "offset common to all pixels")
    offset_std_mm: float = param(2.0, 0.0, 20.0, "mm", "pixel-to-pixel offset spread")
    gain_std: float = param(0.005, 0.0, 0.06, "1", "pixel-to-pixel gain spread")
    seed: int = param(20160516, 0, 2**31 - 1, "1", "seed of the fixed pattern", fit=False)


class PixelOffset(Effect):
    name = "pixel_offset"
    stage = "range"
    nominal = True
    summary = "fixed-pattern per-pixel range offset and gain"
    Params = PixelOffsetParams

    def apply(self, x: np.ndarray, params: PixelOffsetParams,
              ctx: RenderContext) -> np.ndarray:
        offset, gain = offset_pattern(ctx.intrinsics, int(params.seed),
                                      float(params.offset_mean_mm),
                                      float(params.offset_std_mm), float(params.gain_std))
        return offset + (1.0 + gain) * x
