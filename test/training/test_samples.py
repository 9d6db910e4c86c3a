"""Training samples: gathered patches == whole-frame encoding, targets, labels, sampling."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.ndimage import binary_dilation
from synthetic_training_frames import synthetic_frames

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.correction import edges
from tof_mpd_ros.correction.encoding import EncodingConfig, encode_frame
from tof_mpd_ros.errors import InputError
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.training.samples import (
    auto_encoding,
    distortion_clip_mm,
    prepare_training_data,
    sample_pixels,
)

H, W = 40, 48


@pytest.fixture(scope="module")
def frames():
    return synthetic_frames(3, seed=10)


@pytest.fixture(scope="module")
def calib():
    rng = np.random.default_rng(0)
    return IntrinsicCalibration(rng.normal(0, 2, (H, W)), np.ones((H, W)),
                                rng.normal(0, 1, (H, W)), np.ones((H, W), bool))


def test_gathered_patches_equal_frame_encoding(frames, calib) -> None:
    enc = auto_encoding(frames, calib, EncodingConfig())
    data = prepare_training_data(frames, calib, enc)
    flat = sample_pixels(data, [0, 1, 2], None, torch.Generator().manual_seed(0))
    feats, target, group = data.gather(flat)
    ranges = np.stack([calib.apply(f.range_mm, f.amplitude) for f in frames])
    amps = np.stack([f.amplitude for f in frames])
    full, _ = encode_frame(ranges, amps, enc)
    torch.testing.assert_close(feats, full[flat], rtol=0, atol=0)
    # targets: truncated R* - R of the calibrated range, in mm
    ref = np.stack([f.reference_mm for f in frames]).reshape(-1)
    expected = np.clip(ref - ranges.reshape(-1), -15, 15)[flat.numpy()]
    np.testing.assert_allclose(target.numpy(), expected, atol=1e-4)
    assert target.abs().max() <= 15.0 and (target.abs() == 15.0).any()
    # labels: the orientation groups of the ground-truth edges of the reference
    gt = np.stack([edges.ground_truth_edges(f.reference_mm)[1] for f in frames]).reshape(-1)
    np.testing.assert_array_equal(group.numpy(), gt[flat.numpy()])
    assert (group >= 0).any()


def test_missing_reference_and_invalid_pixels_are_excluded(frames, calib) -> None:
    data = prepare_training_data(frames, calib, EncodingConfig())
    ref = np.stack([f.reference_mm for f in frames])
    usable = data.usable.numpy()
    assert not usable[np.isnan(ref)].any()
    assert usable.sum() == np.isfinite(ref).sum()       # every ToF pixel here is valid
    flat = sample_pixels(data, [0, 1, 2], None, torch.Generator().manual_seed(0))
    assert flat.numel() == usable.sum() and torch.isfinite(data.target.reshape(-1)[flat]).all()


def test_sampling_cap_is_per_frame_and_seeded(frames, calib) -> None:
    data = prepare_training_data(frames, calib, EncodingConfig())
    a = sample_pixels(data, [0, 2], 100, torch.Generator().manual_seed(1))
    b = sample_pixels(data, [0, 2], 100, torch.Generator().manual_seed(1))
    c = sample_pixels(data, [0, 2], 100, torch.Generator().manual_seed(2))
    assert torch.equal(a, b) and not torch.equal(a, c)
    frame_of = (a // (H * W)).numpy()
    assert np.bincount(frame_of, minlength=3).tolist() == [100, 0, 100]
    assert len(set(a.tolist())) == 200                    # without replacement


def test_frames_need_reference_and_matching_size(frames, calib) -> None:
    from dataclasses import replace

    with pytest.raises(InputError, match="frame 1 has no reference_mm"):
        prepare_training_data([frames[0], replace(frames[1], reference_mm=None)], calib,
                              EncodingConfig())
    with pytest.raises(InputError, match="crop the frames"):
        prepare_training_data(frames, IntrinsicCalibration.identity(H, W + 2), EncodingConfig())
    with pytest.raises(InputError, match="at least one frame"):
        prepare_training_data([], calib, EncodingConfig())


def test_auto_bins_span_the_data(frames, calib) -> None:
    enc = auto_encoding(frames, calib, EncodingConfig())
    ranges = np.stack([calib.apply(f.range_mm, f.amplitude) for f in frames])
    assert np.nanmin(ranges) <= enc.range_min_mm + 5 and enc.range_max_mm <= np.nanmax(ranges)
    assert 0 < enc.amplitude_min < enc.amplitude_max


def test_data_driven_truncation_follows_the_distortion(frames, calib) -> None:
    """T = the 99th percentile of |R* − R| away from the edges, never under the paper's 15 mm;
    mixed pixels on the depth edges (off by the step itself) do not move it, and the targets
    are clipped at it."""
    rng = np.random.default_rng(1)
    d = np.concatenate([rng.uniform(-40.0, 40.0, 9950), np.full(50, 500.0)])  # flying pixels
    calibrated = np.zeros_like(d)
    t = distortion_clip_mm(calibrated, d)
    assert 39.0 <= t <= 41.0   # the quantile of |U(-40, 40)| ∪ outliers, rounded up
    assert distortion_clip_mm(calibrated[:9950], 0.1 * d[:9950]) == 15.0  # small: the paper's
    assert distortion_clip_mm(calibrated[:4], np.full(4, np.nan)) == 15.0  # nothing to go by
    data = prepare_training_data(frames, calib, EncodingConfig(), target_clip_mm=None)
    ranges = np.stack([calib.apply(f.range_mm, f.amplitude) for f in frames])
    ref = np.stack([f.reference_mm for f in frames])
    near_edge = np.stack([binary_dilation(edges.ground_truth_edges(r)[0], iterations=2)
                          for r in ref])
    usable = data.usable.numpy()
    expected = distortion_clip_mm(ranges[usable & ~near_edge], ref[usable & ~near_edge])
    assert data.target_clip_mm == expected
    # 25 mm of multipath everywhere sets T; 300 mm mixed pixels on the edges do not move it
    deep = [ToFFrame(f.reference_mm - 25.0, f.amplitude, f.intrinsics,
                     reference_mm=f.reference_mm) for f in frames]
    t_deep = prepare_training_data(deep, calib, EncodingConfig(), target_clip_mm=None)
    assert 25.0 < t_deep.target_clip_mm < 35.0
    mixed = [ToFFrame(np.where(binary_dilation(edges.ground_truth_edges(f.reference_mm)[0]),
                               f.range_mm - 300.0, f.range_mm), f.amplitude, f.intrinsics,
                      reference_mm=f.reference_mm) for f in deep]
    assert prepare_training_data(mixed, calib, EncodingConfig(),
                                 target_clip_mm=None).target_clip_mm == t_deep.target_clip_mm
    assert float(np.nanmax(np.abs(data.target.numpy()))) <= expected
