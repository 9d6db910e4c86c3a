"""Per-pixel intrinsic calibration: recovers a known per-pixel linear distortion, from arrays,
from checkerboard frames and from a capture file (the CLI's one fit)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tof_mpd_ros.calibration import (
    IntrinsicCalibration,
    fit_calibration,
    load_calibration,
    save_calibration,
)
from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.cli import calibrate as calibrate_cli
from tof_mpd_ros.errors import CalibrationError, InputError
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.recordings import write_frames

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



def test_saved_calibration_loads_back_and_replaces_the_old_file_whole(tmp_path: Path) -> None:
    observed, amp, true, _ = _distorted_stack(5)
    calib = IntrinsicCalibration.fit(observed, amp, true, amplitude_term="inverse")
    save_calibration(tmp_path / "calib", calib)   # like np.savez: ".npz" is appended
    path = tmp_path / "calib.npz"
    back = load_calibration(path)
    np.testing.assert_array_equal(back.apply(observed[0], amp[0]), calib.apply(observed[0], amp[0]))
    identity = IntrinsicCalibration.identity(H, W)
    save_calibration(path, identity)
    np.testing.assert_array_equal(load_calibration(path).apply(observed[0], amp[0]),
                                  identity.apply(observed[0], amp[0]))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["calib.npz"]  # no temporary left

def _boards(seed: int = 0) -> tuple[list[ToFFrame], np.ndarray]:
    """12 checkerboard frames of a known per-pixel model; returns them and its c1."""
    rng = np.random.default_rng(seed)
    c0, c1, c2 = rng.normal(0, 10, (H, W)), rng.uniform(0.97, 1.03, (H, W)), rng.normal(
        0, 5, (H, W))
    boards = []
    for i in range(12):
        true = rng.uniform(250, 500) + rng.normal(0, 20, (H, W))
        amp = rng.uniform(0.1, 1.0, (H, W))
        obs = (true - c0 - c2 * amp) / c1
        boards.append(ToFFrame(obs, amp, Intrinsics.from_fov(W, H, 40.0), reference_mm=true,
                               stamp_ns=1000 * (i + 1)))
    return boards, c1


def test_fit_calibration_from_checkerboard_frames() -> None:
    boards, c1 = _boards()
    calib = fit_calibration(boards, ridge=1e-6)
    np.testing.assert_allclose(calib.c1, c1, atol=1e-4)
    with pytest.raises(CalibrationError, match="got none"):
        fit_calibration([])
    with pytest.raises(CalibrationError, match="frame 1 has no reference_mm"):
        fit_calibration([boards[0], replace(boards[1], reference_mm=None)])
    small = replace(boards[1], range_mm=boards[1].range_mm[1:], amplitude=boards[1].amplitude[1:],
                    reference_mm=boards[1].reference_mm[1:],
                    intrinsics=Intrinsics.from_fov(W, H - 1, 40.0))
    with pytest.raises(CalibrationError, match="frame 1 is"):
        fit_calibration([boards[0], small])


def test_the_cli_fits_with_the_one_fit(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # `tof-mpd calibrate intrinsic` (and train, demo) fit through calibration.fit_calibration,
    # on the frames of the file that carry a reference, with the chosen amplitude term.
    boards, _ = _boards(1)
    no_reference = replace(boards[0], reference_mm=None, stamp_ns=99_000)
    write_frames(tmp_path / "captures", [*boards, no_reference])  # a recording keeps None
    calls = []

    def spy(frames, **kwargs):
        calls.append((len(frames), kwargs))
        return fit_calibration(frames, **kwargs)

    monkeypatch.setattr(calibrate_cli, "fit_calibration", spy)
    calib, used = calibrate_cli.fit_from_file(tmp_path / "captures", "inverse")
    assert calls == [(12, {"amplitude_term": "inverse"})] and len(used) == 12
    want = fit_calibration(used, amplitude_term="inverse")
    for name in ("c0", "c1", "c2", "fitted", "rms_mm"):
        np.testing.assert_array_equal(getattr(calib, name), getattr(want, name), err_msg=name)
