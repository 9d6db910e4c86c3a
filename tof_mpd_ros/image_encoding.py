"""``sensor_msgs/Image`` payloads <-> numpy, and REP 118 depth units.

Works on the message *fields* (encoding, height, width, step, is_bigendian, data), so it serves
rclpy messages, MCAP-decoded messages and tests alike without importing ROS.

REP 118 depth images: ``32FC1`` in metres (NaN/inf = invalid) or ``16UC1`` in millimetres
(0 = invalid). ``64FC1`` (metres) is accepted too: it round-trips float32 millimetres exactly.
"""

from __future__ import annotations

import numpy as np

from .errors import InputError

# encoding -> (numpy dtype, channels)
PIXEL_FORMATS: dict[str, tuple[np.dtype, int]] = {
    "32FC1": (np.dtype(np.float32), 1),
    "64FC1": (np.dtype(np.float64), 1),
    "16UC1": (np.dtype(np.uint16), 1),
    "mono16": (np.dtype(np.uint16), 1),
    "8UC1": (np.dtype(np.uint8), 1),
    "mono8": (np.dtype(np.uint8), 1),
}
# Depth encodings and the factor that turns their values into millimetres.
DEPTH_MM_PER_UNIT = {"32FC1": 1000.0, "64FC1": 1000.0, "16UC1": 1.0, "mono16": 1.0}


def image_to_array(encoding: str, height: int, width: int, step: int, is_bigendian: bool,
                   data: bytes | bytearray | memoryview | np.ndarray) -> np.ndarray:
    """Decode an image payload.

    Returns:
        (height, width) array of the encoding's dtype in native byte order (a copy).

    Raises:
        InputError: unsupported encoding, or a payload whose size does not match
            ``height * step`` / a ``step`` too small for ``width``.
    """
    if encoding not in PIXEL_FORMATS:
        raise InputError(f"unsupported image encoding {encoding!r}; expected one of "
                         f"{sorted(PIXEL_FORMATS)}")
    dtype, channels = PIXEL_FORMATS[encoding]
    row_bytes = width * channels * dtype.itemsize
    # The payload's bytes, whatever holds them (an ndarray of another dtype is not value-cast)
    raw = np.ascontiguousarray(data).reshape(-1) if isinstance(data, np.ndarray) else data
    buffer = np.frombuffer(memoryview(raw).cast("B"), dtype=np.uint8)
    if height <= 0 or width <= 0:
        raise InputError(f"image has an empty size {width}x{height}")
    if step < row_bytes or buffer.size != height * step:
        raise InputError(f"{encoding} image {width}x{height}: expected {height}x{step} bytes "
                         f"with step >= {row_bytes}, got {buffer.size} bytes, step {step}")
    rows = buffer.reshape(height, step)[:, :row_bytes]
    dt = dtype.newbyteorder(">" if is_bigendian else "<")
    return np.ascontiguousarray(rows).view(dt).reshape(height, width).astype(dtype)


def array_to_image_data(array: np.ndarray, encoding: str) -> tuple[int, bytes]:
    """Encode an (H, W) array as a little-endian payload; returns ``(step, data)``."""
    if encoding not in PIXEL_FORMATS:
        raise InputError(f"unsupported image encoding {encoding!r}")
    dtype, _ = PIXEL_FORMATS[encoding]
    if array.ndim != 2:
        raise InputError(f"expected an (H, W) array, got shape {array.shape}")
    out = np.ascontiguousarray(array, dtype=dtype.newbyteorder("<"))
    return out.shape[1] * dtype.itemsize, out.tobytes()


def depth_to_mm(depth: np.ndarray, encoding: str) -> np.ndarray:
    """Depth values of a REP 118 encoding -> float32 millimetres, invalid -> NaN.

    Args:
        depth: (H, W) array as decoded by :func:`image_to_array`.
        encoding: its encoding (``32FC1``/``64FC1`` metres, ``16UC1``/``mono16`` millimetres).
    """
    if encoding not in DEPTH_MM_PER_UNIT:
        raise InputError(f"{encoding!r} is not a depth encoding; expected one of "
                         f"{sorted(DEPTH_MM_PER_UNIT)} (REP 118)")
    mm = depth.astype(np.float64) * DEPTH_MM_PER_UNIT[encoding]
    mm[~np.isfinite(mm) | (mm <= 0)] = np.nan
    return mm.astype(np.float32)


def mm_to_depth(depth_mm: np.ndarray, encoding: str) -> np.ndarray:
    """Float millimetres (NaN = invalid) -> values of a REP 118 encoding.

    ``16UC1`` rounds to whole millimetres and writes 0 for invalid or out-of-range pixels;
    float encodings keep NaN.
    """
    if encoding not in DEPTH_MM_PER_UNIT:
        raise InputError(f"{encoding!r} is not a depth encoding (REP 118)")
    mm = np.asarray(depth_mm, dtype=np.float64)
    if encoding in ("16UC1", "mono16"):
        valid = np.isfinite(mm) & (mm > 0) & (mm < 65535.5)
        return np.where(valid, np.rint(np.where(valid, mm, 0)), 0).astype(np.uint16)
    dtype = PIXEL_FORMATS[encoding][0]
    return (mm / DEPTH_MM_PER_UNIT[encoding]).astype(dtype)


def amplitude_to_float(amplitude: np.ndarray) -> np.ndarray:
    """Any decoded amplitude/IR image -> (H, W) float32, non-finite -> NaN."""
    out = amplitude.astype(np.float32)
    out[~np.isfinite(out)] = np.nan
    return out
