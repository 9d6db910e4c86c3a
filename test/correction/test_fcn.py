"""The fcn model kind: receptive field, residual output (no blur across edges), sigma gating,
the Gaussian likelihood, and its weights file."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy import stats
from weights_files import rewrite_weights

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.correction.fcn import (
    FCNArchitecture,
    FCNCorrectionModel,
    ResidualFCN,
    fcn_inputs,
    gaussian_nll,
    receptive_field_px,
    run_fcn,
)
from tof_mpd_ros.correction.pipeline import correct
from tof_mpd_ros.correction.weights import load_weights, save_weights
from tof_mpd_ros.errors import InputError, WeightsError

H, W = 50, 70   # not multiples of 16: the padding path is exercised


def _calibration(seed: int = 0) -> IntrinsicCalibration:
    rng = np.random.default_rng(seed)
    return IntrinsicCalibration(rng.normal(0, 3, (H, W)), rng.uniform(0.98, 1.02, (H, W)),
                                rng.normal(0, 1, (H, W)), np.ones((H, W), bool))


def _step_frame() -> tuple[np.ndarray, np.ndarray]:
    """A 300 mm plane with a 400 mm right half (a depth edge), some invalid pixels."""
    r = np.full((H, W), 300.0, np.float32)
    r[:, W // 2:] = 400.0
    a = np.full((H, W), 50.0, np.float32)
    r[3, 4] = np.nan
    a[5, 6] = 0.0
    return r, a


def _constant_head(model: FCNCorrectionModel, correction_mm: float, sigma_raw: float) -> None:
    """Make the network output a constant correction and sigma (head weights zeroed)."""
    arch = model.architecture
    with torch.no_grad():
        model.net.head.weight.zero_()
        model.net.head.bias.copy_(torch.tensor([correction_mm / arch.correction_scale_mm,
                                                sigma_raw]))


def test_receptive_field_reaches_beyond_64_px() -> None:
    net = ResidualFCN(generator=torch.Generator().manual_seed(0))
    assert receptive_field_px(net) >= 128
    # two levels see far less: the measurement is not a constant
    small = ResidualFCN(FCNArchitecture(widths=(4, 4)), generator=torch.Generator().manual_seed(0))
    assert 15 <= receptive_field_px(small) <= 25   # 5 + 2 + 8 + bilinear + 4 px by hand


def test_output_is_the_pixels_own_range_plus_a_correction_no_blur_across_edges() -> None:
    model = FCNCorrectionModel.untrained(IntrinsicCalibration.identity(H, W), seed=1)
    _constant_head(model, correction_mm=2.5, sigma_raw=-3.0)
    r, a = _step_frame()
    res = correct(model, r, a)
    calibrated = model.calibration.apply(r, a)
    ok = res.valid
    np.testing.assert_allclose(res.range_mm[ok], calibrated[ok] + 2.5, atol=1e-4)
    # the edge columns keep their own sides: only 302.5 and 402.5 mm appear
    assert set(np.unique(res.range_mm[ok]).round(3)) == {302.5, 402.5}
    assert not ok[3, 4] and not ok[5, 6]
    assert np.isnan(res.range_mm[3, 4]) and res.confidence[5, 6] == 0


def test_sigma_gates_the_output_and_sets_the_confidence() -> None:
    model = FCNCorrectionModel.untrained(_calibration(), seed=2, max_sigma_mm=4.0)
    arch = model.architecture
    # sigma = floor + scale * softplus(raw): choose raw so sigma = 3 mm, then 6 mm
    for sigma_mm, kept in ((3.0, True), (6.0, False)):
        raw = math.log(math.expm1((sigma_mm - arch.sigma_floor_mm) / arch.sigma_scale_mm))
        _constant_head(model, 0.0, raw)
        res = correct(model, *_step_frame())
        ok = res.valid
        np.testing.assert_allclose(res.sigma_mm[ok], sigma_mm, rtol=1e-5)
        assert np.isfinite(res.range_mm[ok]).all() == kept
        assert np.isfinite(res.range_f_mm[ok]).all()     # the ungated correction stays
        np.testing.assert_allclose(res.confidence[ok], max(0.0, 1 - sigma_mm / 4.0), atol=1e-6)
        assert (res.confidence[~ok] == 0).all() and not res.edges.any()


def test_batch_equals_single_frames_and_net_off_gives_calibrated() -> None:
    model = FCNCorrectionModel.untrained(_calibration(), seed=3)
    rng = np.random.default_rng(0)
    r = rng.uniform(250, 450, (2, H, W)).astype(np.float32)
    a = rng.uniform(10, 90, (2, H, W)).astype(np.float32)
    both = correct(model, r, a)
    for i in range(2):
        one = correct(model, r[i], a[i])
        np.testing.assert_allclose(one.range_f_mm, both.range_f_mm[i], atol=1e-4)
    off = correct(model, r, a, use_range_net=False)
    np.testing.assert_array_equal(off.range_mm, model.calibration.apply(r, a))


def test_inputs_are_relative_to_the_frame_except_the_absolute_range_plane() -> None:
    rng = np.random.default_rng(4)
    r = rng.uniform(250, 450, (1, H, W)).astype(np.float32)
    a = rng.uniform(10, 90, (1, H, W)).astype(np.float32)
    x0, valid = fcn_inputs(r, a, 16)
    x1, _ = fcn_inputs(r + 100, a * 7, 16)
    assert x0.shape == (1, 4, 64, 80) and valid.all()
    torch.testing.assert_close(x0[:, [0, 2, 3]], x1[:, [0, 2, 3]], atol=1e-5, rtol=0)
    torch.testing.assert_close(x1[0, 1, :H, :W] - x0[0, 1, :H, :W],
                               torch.full((H, W), 0.1), atol=1e-5, rtol=0)
    assert float(x0[0, :, H:, :].abs().sum()) == 0     # padding is zero, marked invalid


def test_gaussian_nll_is_the_normal_log_density_and_is_lowest_at_the_true_sigma() -> None:
    gen = torch.Generator().manual_seed(0)
    t = 2.0 * torch.randn(1, 100, 100, generator=gen)
    mask = torch.ones_like(t, dtype=torch.bool)
    mask[0, :10] = False
    mu = torch.zeros_like(t)
    nll = gaussian_nll(mu, torch.full_like(t, 2.0), t, mask)
    expected = -stats.norm.logpdf(t[mask].numpy(), scale=2.0).mean()
    assert float(nll) == pytest.approx(expected, rel=1e-5)
    at = {s: float(gaussian_nll(mu, torch.full_like(t, s), t, mask)) for s in (1.5, 2.0, 2.6)}
    assert at[2.0] < at[1.5] and at[2.0] < at[2.6]
    # masked-out pixels do not count, however wrong
    t2 = t.clone()
    t2[~mask] = 1e6
    assert float(gaussian_nll(mu, torch.full_like(t, 2.0), t2, mask)) == pytest.approx(
        float(nll), rel=1e-6)


def test_architecture_is_validated() -> None:
    with pytest.raises(InputError):
        FCNArchitecture(widths=(8,))
    with pytest.raises(InputError):
        FCNArchitecture(sigma_floor_mm=0.0)
    with pytest.raises(InputError):
        FCNCorrectionModel.untrained(_calibration(), max_sigma_mm=0.0)


def test_weights_round_trip_of_the_fcn_kind(tmp_path: Path) -> None:
    model = FCNCorrectionModel.untrained(_calibration(), FCNArchitecture(widths=(4, 8, 8)),
                                         seed=5, max_sigma_mm=7.5)
    model.metadata["note"] = "unit test"
    path = save_weights(tmp_path / "fcn.npz", model)
    back = load_weights(path, expected_shape=(H, W))
    assert isinstance(back, FCNCorrectionModel) and back.kind == "fcn"
    assert back.max_sigma_mm == 7.5 and back.architecture == model.architecture
    assert back.metadata["note"] == "unit test" and back.metadata["file"]["kind"] == "fcn"
    r, a = _step_frame()
    cal = model.calibration.apply(r, a)[None]
    for got, want in zip(run_fcn(back.net, cal, a[None]), run_fcn(model.net, cal, a[None]),
                         strict=True):
        np.testing.assert_array_equal(got, want)


def test_fcn_weights_that_do_not_fit_are_refused(tmp_path: Path) -> None:
    model = FCNCorrectionModel.untrained(_calibration(), FCNArchitecture(widths=(4, 8)), seed=6)
    src = save_weights(tmp_path / "fcn.npz", model)

    def widen(arrays, meta):
        meta["architecture"]["fcn"]["widths"] = [4, 16]

    def unknown_kind(arrays, meta):
        meta["kind"] = "transformer"

    def patch_arrays_in_fcn(arrays, meta):
        arrays["range_net/w"] = np.zeros(3, np.float32)

    for edit, words in ((widen, "declared architecture"), (unknown_kind, "transformer"),
                        (patch_arrays_in_fcn, "unexpected entries")):
        bad = rewrite_weights(src, tmp_path / f"{edit.__name__}.npz", edit)
        with pytest.raises(WeightsError, match=words):
            load_weights(bad)
