"""Per-pixel intrinsic calibration: recovers a known per-pixel linear distortion."""

from __future__ import annotations

import numpy as np
import pytest

from tof_mpd_ros.correction.calibration import IntrinsicCalibration
from tof_mpd_ros.errors import CalibrationError, InputError

H, W, N = 12, 16, 40


def _distorted_stack(seed: int, term: str = "linear"):
    """True ranges, amplitudes and observations from a known per-pixel inverse model."""
    rng = np.random.default_rng(seed)
    true = rng.uniform(200, 600, (N, H, W))
    amp = rng.uniform(0.05, 1.0, (N, H, W))
    c0 = rng.uniform(-20, 20, (H, W))
    c1 = rng.uniform(0.95, 1.05, (H, W))
    c2 = rng.uniform(-8, 8, (H, W))
    a_feat = amp if term == "linear" else 1.0 / amp
    # observed chosen so that true = c0 + c1 * observed + c2 * a(amp) exactly
    observed = (true - c0 - c2 * a_feat) / c1
    return observed, amp, true, (c0, c1, c2)


@pytest.mark.parametrize("term", ["linear", "inverse"])
def test_fit_recovers_known_per_pixel_model(term: str) -> None:
    observed, amp, true, (c0, c1, c2) = _distorted_stack(0, term)
    calib = IntrinsicCalibration.fit(observed, amp, true, amplitude_term=term, ridge=1e-6)
    np.testing.assert_allclose(calib.c1, c1, atol=1e-5)
    np.testing.assert_allclose(calib.c2, c2, atol=1e-3)
    np.testing.assert_allclose(calib.c0, c0, atol=5e-3)
    assert calib.fitted.all()
    assert np.nanmax(calib.rms_mm) < 1e-3
    # and applying it to new observations gives the true range back
    new_obs, new_amp, new_true, _ = _distorted_stack(0, term)
    np.testing.assert_allclose(calib.apply(new_obs[:3], new_amp[:3]), new_true[:3], atol=0.02)


def test_fit_is_nan_aware_and_noise_robust() -> None:
    observed, amp, true, (c0, c1, c2) = _distorted_stack(1)
    rng = np.random.default_rng(2)
    noisy = observed + rng.normal(0, 0.5, observed.shape)
    holes = rng.random(observed.shape) < 0.3
    noisy[holes] = np.nan
    true = true.copy()
    true[rng.random(true.shape) < 0.1] = np.nan       # missing reference
    amp = amp.copy()
    amp[rng.random(amp.shape) < 0.05] = 0.0            # zero amplitude = invalid
    calib = IntrinsicCalibration.fit(noisy, amp, true)
    err = calib.apply(observed, amp) - (c0 + c1 * observed + c2 * amp)
    # noise 0.5 mm, ~25 samples per pixel: the fitted model is within ~0.3 mm
    assert np.sqrt(np.nanmean(err ** 2)) < 0.3
    assert 0.3 < np.nanmedian(calib.rms_mm) < 0.7


def test_ridge_keeps_sparse_pixels_finite_and_centred() -> None:
    observed, amp, true, _ = _distorted_stack(3)
    observed[3:, 0, 0] = np.nan                    # pixel (0,0): only 3 samples
    amp[:, 0, 1] = 0.5                             # pixel (0,1): constant amplitude (degenerate)
    calib = IntrinsicCalibration.fit(observed, amp, true, ridge=1.0)
    assert calib.fitted[0, 0] and np.isfinite(calib.c0).all()
    resid = calib.apply(observed[:3, 0, 0][:, None, None] * np.ones((3, H, W)),
                        amp[:3, 0, 0][:, None, None] * np.ones((3, H, W)))[:, 0, 0] - true[:3, 0, 0]
    assert abs(resid.mean()) < 1.0                 # offset kept even when slopes are shrunk


def test_too_few_samples_raise_clear_error() -> None:
    observed, amp, true, _ = _distorted_stack(4)
    observed[2:, :, : W // 2] = np.nan             # half the pixels see only 2 captures
    with pytest.raises(CalibrationError, match=r"too few valid samples: 50\.0% of pixels"):
        IntrinsicCalibration.fit(observed, amp, true, min_samples=3)
    with pytest.raises(CalibrationError, match="at least 3 captures, got 2"):
        IntrinsicCalibration.fit(observed[:2], amp[:2], true[:2])
    with pytest.raises(CalibrationError, match="no valid sample"):
        IntrinsicCalibration.fit(observed * np.nan, amp, true)
    with pytest.raises(CalibrationError, match="expected shape"):
        IntrinsicCalibration.fit(observed, amp[:, :-1], true)


def test_identity_apply_and_invalid_pixels() -> None:
    calib = IntrinsicCalibration.identity(H, W)
    assert calib.is_identity
    r = np.full((H, W), 300.0, np.float32)
    a = np.full((H, W), 0.5, np.float32)
    r[0, 0], r[0, 1], a[0, 2], r[0, 3] = np.nan, np.inf, 0.0, -1.0
    out = calib.apply(r, a)
    assert out.dtype == np.float32
    assert np.isnan(out[0, :4]).all()
    assert (out[1:] == 300.0).all()
    with pytest.raises(InputError, match="expected shape"):
        calib.apply(np.zeros((H + 1, W)), np.zeros((H + 1, W)))


def test_arrays_round_trip() -> None:
    observed, amp, true, _ = _distorted_stack(5)
    calib = IntrinsicCalibration.fit(observed, amp, true, amplitude_term="inverse")
    arrays = calib.to_arrays()
    assert all(v.dtype != object for v in arrays.values())
    back = IntrinsicCalibration.from_arrays(arrays)
    assert back.amplitude_term == "inverse"
    np.testing.assert_array_equal(back.apply(observed[0], amp[0]), calib.apply(observed[0], amp[0]))
    with pytest.raises(CalibrationError, match="missing: c2"):
        IntrinsicCalibration.from_arrays({k: v for k, v in arrays.items() if k != "c2"})
