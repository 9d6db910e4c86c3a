"""Patch encoding: whole-frame vectorised path == naive per-pixel reference, bit for bit."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from tof_mpd_ros.correction.encoding import EncodingConfig, encode_frame
from tof_mpd_ros.errors import InputError

CFG = EncodingConfig(range_min_mm=150.0, range_max_mm=550.0, amplitude_min=0.0,
                     amplitude_max=2.0)


def _f32(x: float) -> np.float32:
    return np.float32(x)


def naive_encode(range_mm: np.ndarray, amplitude: np.ndarray, cfg: EncodingConfig) -> np.ndarray:
    """Per-pixel Python reference of the documented encoding, (H*W, 280) float32."""
    h, w = range_mm.shape
    half = cfg.patch_size // 2
    r = range_mm.astype(np.float32)
    a = amplitude.astype(np.float32)
    ok = np.isfinite(r) & np.isfinite(a) & (r > 0) & (a > 0)
    log_a = np.where(ok, np.log(np.where(ok, a, 1.0).astype(np.float64)), 0.0).astype(np.float32)
    out = np.zeros((h * w, cfg.n_features), np.float32)
    m = cfg.n_neighbours
    scale_r = _f32(0.5 / _f32(cfg.range_clip_mm))
    scale_a = _f32(0.5 / _f32(cfg.amplitude_log_clip))
    for y in range(h):
        for x in range(w):
            row = out[y * w + x]
            if not ok[y, x]:
                continue
            j = 0
            for dy in range(-half, half + 1):
                for dx in range(-half, half + 1):
                    if dy == 0 and dx == 0:
                        continue
                    qy, qx = y + dy, x + dx
                    if 0 <= qy < h and 0 <= qx < w and ok[qy, qx]:
                        dr = np.clip(r[qy, qx] - r[y, x], -_f32(cfg.range_clip_mm),
                                     _f32(cfg.range_clip_mm))
                        da = np.clip(log_a[qy, qx] - log_a[y, x],
                                     -_f32(cfg.amplitude_log_clip), _f32(cfg.amplitude_log_clip))
                        row[j] = dr * scale_r
                        row[m + j] = da * scale_a
                    j += 1
            for k, (v, lo, hi) in enumerate(((r[y, x], cfg.range_min_mm, cfg.range_max_mm),
                                             (a[y, x], cfg.amplitude_min, cfg.amplitude_max))):
                pos = (v - _f32(lo)) * _f32(cfg.n_bins / (hi - lo))
                b = min(max(math.floor(pos), 0), cfg.n_bins - 1)
                row[2 * m + k * cfg.n_bins + b] = 1.0
    return out


def _random_frame(seed: int, h: int = 17, w: int = 23) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    r = rng.uniform(100, 600, (h, w)).astype(np.float32)
    a = rng.uniform(0.01, 2.5, (h, w)).astype(np.float32)
    r[rng.random((h, w)) < 0.08] = np.nan
    a[rng.random((h, w)) < 0.04] = 0.0
    r[rng.random((h, w)) < 0.02] = np.inf
    return r, a


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_frame_encoding_equals_naive_reference(seed: int) -> None:
    r, a = _random_frame(seed)
    feats, valid = encode_frame(r, a, CFG)
    ref = naive_encode(r, a, CFG)
    assert feats.shape == (r.size, 280) and feats.dtype == torch.float32
    np.testing.assert_array_equal(feats.numpy(), ref)
    expected_valid = np.isfinite(r) & (a > 0)
    np.testing.assert_array_equal(valid.numpy()[0], expected_valid)


def test_batch_equals_frames_and_boundary_only_prefix() -> None:
    frames = [_random_frame(s, 9, 13) for s in (3, 4)]
    r = np.stack([f[0] for f in frames])
    a = np.stack([f[1] for f in frames])
    feats, valid = encode_frame(r, a, CFG)
    assert valid.shape == (2, 9, 13)
    for i, (ri, ai) in enumerate(frames):
        np.testing.assert_array_equal(feats[i * 117:(i + 1) * 117].numpy(),
                                      naive_encode(ri, ai, CFG))
    short, _ = encode_frame(r, a, CFG, boundary_only=True)
    np.testing.assert_array_equal(short.numpy(), feats[:, :240].numpy())


def test_hand_computed_values() -> None:
    """A 40 mm step and a 2x amplitude step, seen from the pixel left of the step."""
    r = np.full((11, 11), 300.0, np.float32)
    r[:, 6:] = 340.0
    a = np.ones((11, 11), np.float32)
    a[:, 6:] = 2.0
    feats, _ = encode_frame(r, a, CFG)
    row = feats[5 * 11 + 5].numpy()      # centre pixel (5, 5), at column 5 of 11
    x_r, x_a = row[:120], row[120:240]
    # neighbour (dy=-5, dx=+1) is patch index 6 (first row, column 6): across the step
    assert x_r[6] == pytest.approx(40.0 / 100.0)      # clip 50 mm -> 40 / (2*50)
    assert x_r[4] == 0.0                               # same surface
    assert x_a[6] == pytest.approx(math.log(2.0) / (2 * math.log(4.0)), rel=1e-6)
    assert np.all(np.abs(row[:240]) <= 0.5)
    # range 300 in [150, 550) with 20 bins -> bin 7; amplitude 1 in [0, 2) -> bin 10
    assert np.flatnonzero(row[240:260]).tolist() == [7]
    assert np.flatnonzero(row[260:280]).tolist() == [10]
    # a 400 mm step saturates at +0.5; out-of-range centre values fall in the end bins
    r2 = r.copy()
    r2[:, 6:] = 2000.0
    row2 = encode_frame(r2, a, CFG)[0][5 * 11 + 9].numpy()   # centre at 2000 mm
    assert np.flatnonzero(row2[240:260]).tolist() == [19]
    assert encode_frame(r2, a, CFG)[0][5 * 11 + 5].numpy()[6] == 0.5


def test_config_validation_and_shape_errors() -> None:
    with pytest.raises(InputError, match="patch_size must be odd"):
        EncodingConfig(patch_size=10)
    with pytest.raises(InputError, match="max > min"):
        EncodingConfig(range_min_mm=500, range_max_mm=100)
    with pytest.raises(InputError, match="got \\(4, 5\\) and \\(4, 6\\)"):
        encode_frame(np.zeros((4, 5)), np.zeros((4, 6)), CFG)
    assert EncodingConfig().n_features == 280 and EncodingConfig().n_boundary_features == 240


def test_sampled_pixels_of_a_stack_hold_the_same_numbers() -> None:
    """encode_pixels (training's batches) on chosen pixels of a stack == encode_frame's rows."""
    from tof_mpd_ros.correction.encoding import encode_pixels, padded_planes

    frames = [_random_frame(s, 9, 13) for s in (5, 6, 7)]
    r = np.stack([f[0] for f in frames])
    a = np.stack([f[1] for f in frames])
    feats, valid = encode_frame(r, a, CFG)
    planes = padded_planes(r, a, CFG)
    np.testing.assert_array_equal(planes.valid, valid.numpy())
    pick = np.random.default_rng(0).permutation(r.size)[:200]
    for boundary_only in (False, True):
        got = encode_pixels(planes.range_mm, planes.log_amplitude, planes.amplitude, pick, CFG,
                            boundary_only=boundary_only)
        np.testing.assert_array_equal(got, feats.numpy()[pick, :got.shape[1]])
    # into a caller's larger buffer (the pipeline's recheck): its first rows, the rest kept
    buf = np.full((300, CFG.n_boundary_features), 7.0, np.float32)
    got = encode_pixels(planes.range_mm, planes.log_amplitude, planes.amplitude, pick, CFG,
                        boundary_only=True, out=buf)
    assert got is buf
    np.testing.assert_array_equal(buf[:200], feats.numpy()[pick, :CFG.n_boundary_features])
    assert (buf[200:] == 7.0).all()
    with pytest.raises(InputError, match="out must be"):
        encode_pixels(planes.range_mm, planes.log_amplitude, planes.amplitude, pick, CFG,
                      boundary_only=True, out=buf[:100])


def test_fast_path_kernels_hold_the_same_numbers() -> None:
    from tof_mpd_ros.correction.encoding import encode_band, frame_planes, plane_constants

    for seed in (7, 8):
        r, a = _random_frame(seed)
        r[0, 1] = -3.0                               # invalid: range <= 0
        a[2, 2] = np.inf                             # invalid: amplitude not finite
        feats, valid = encode_frame(r, a, CFG)
        h, w = r.shape
        half = CFG.patch_size // 2
        r_pad = np.full((h + 2 * half, w + 2 * half), np.nan, np.float32)
        la_pad = np.full_like(r_pad, np.nan)
        bins_r, bins_a = np.zeros(h * w, np.int32), np.zeros(h * w, np.int32)
        ok = np.zeros((h, w), bool)
        consts = plane_constants(CFG)
        frame_planes(r.astype(np.float32), a.astype(np.float32), consts, CFG.n_bins, r_pad,
                     la_pad, bins_r, bins_a, ok)
        np.testing.assert_array_equal(ok, valid[0].numpy())
        flat_ok = ok.reshape(-1)
        np.testing.assert_array_equal(bins_r[flat_ok], feats[:, 240:260].argmax(1).numpy()[flat_ok])
        np.testing.assert_array_equal(bins_a[flat_ok], feats[:, 260:280].argmax(1).numpy()[flat_ok])
        assert not bins_r[~flat_ok].any() and not bins_a[~flat_ok].any()
        out = np.full((240, h * w), 99.0, np.float32)
        for y0 in range(0, h, 3):                    # bands of 3 rows, the last one shorter
            y1 = min(h, y0 + 3)
            band = np.full((240, (y1 - y0) * w), 99.0, np.float32)
            encode_band(r_pad, la_pad, y0, y1, CFG.patch_size, consts, band)
            out[:, y0 * w:y1 * w] = band
        np.testing.assert_array_equal(out.T, feats[:, :240].numpy())   # bit for bit


def test_int8_rows_are_the_float_rows_quantised() -> None:
    """encode_band_int8 == rint(254 x) of the float encoding, element for element; equal
    neighbours and invalid ones read exactly 0, a saturated difference +-127."""
    from tof_mpd_ros.correction.encoding import (
        INT8_SCALE,
        encode_band_int8,
        padded_planes,
        plane_constants,
        quantize_rows,
    )

    r, a = _random_frame(9)
    r[5, 5:12] = r[5, 4]                             # equal neighbours: x = 0 exactly
    r[8, 8] = r[8, 9] + 400.0                        # a saturated step: x = -0.5 to its right
    feats, _ = encode_frame(r, a, CFG)
    xf = feats[:, :240].numpy()
    planes = padded_planes(r[None], a[None], CFG)
    h, w = r.shape
    out = np.full((h * w, 240), 99, np.int8)
    for y0 in range(0, h, 4):
        y1 = min(h, y0 + 4)
        band = np.full((240, (y1 - y0) * w), 99, np.int8)          # feature-major
        encode_band_int8(planes.range_mm[0], planes.log_amplitude[0], y0, y1, CFG.patch_size,
                         plane_constants(CFG), band)
        out[y0 * w:y1 * w] = band.T
    want = np.rint(xf.astype(np.float32) * np.float32(INT8_SCALE))   # half to even
    np.testing.assert_array_equal(out.astype(np.float64), want)
    assert out.min() == -127 and out.max() == 127 and (out[xf == 0] == 0).all()
    assert (out[8 * w + 8, :] != 0).any()
    np.testing.assert_array_equal(out[(xf == 0).all(1)], 0)           # invalid centres
    q = np.empty_like(out)
    quantize_rows(np.ascontiguousarray(xf), q)                        # the one quantisation
    np.testing.assert_array_equal(q, out)
    # a step is 1/254 of x: 100/254 mm of range difference at D = 50 mm
    assert abs(2 * CFG.range_clip_mm / INT8_SCALE - 0.3937) < 1e-4
