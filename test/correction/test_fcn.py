"""The fcn model kind: receptive field, gated kernel plus residual output (no blur across
edges), sigma gating, the Gaussian likelihood, and its weights file."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from oracles.kernel_mean import kernel_mean_shift_reference
from scipy import stats
from weights_files import rewrite_weights

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.correction.fcn import (
    DETAIL_CLIP_MM,
    LOG_AMPLITUDE_SCALE,
    FCNArchitecture,
    FCNCorrectionModel,
    ResidualFCN,
    _kernel_mean_shift_torch,
    fcn_inputs,
    gaussian_nll,
    kernel_mean_shift,
    pad_to_multiple,
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


def _constant_head(model: FCNCorrectionModel, correction_mm: float, sigma_raw: float,
                   kernel_logits: np.ndarray | None = None) -> None:
    """Make the network output a constant correction, sigma and kernel logits (all 0 = equal
    weights; head weights zeroed)."""
    arch = model.architecture
    logits = np.zeros(arch.kernel_px ** 2) if kernel_logits is None else kernel_logits
    with torch.no_grad():
        model.net.head.weight.zero_()
        model.net.head.bias.copy_(torch.tensor(
            [correction_mm / arch.correction_scale_mm, sigma_raw, *logits], dtype=torch.float32))


def test_receptive_field_reaches_beyond_64_px() -> None:
    net = ResidualFCN(generator=torch.Generator().manual_seed(0))
    assert receptive_field_px(net) >= 128
    # two levels see far less: the measurement is not a constant
    small = ResidualFCN(FCNArchitecture(widths=(4, 4)), generator=torch.Generator().manual_seed(0))
    assert 15 <= receptive_field_px(small) <= 25   # 5 + 2 + 8 + bilinear + 4 px by hand


def test_no_blur_across_a_depth_edge_whatever_the_kernel() -> None:
    # equal weights over the whole 5 x 5 kernel: only the gate keeps the sides apart
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


def test_kernel_is_a_gated_weighted_mean_of_the_neighbours() -> None:
    model = FCNCorrectionModel.untrained(IntrinsicCalibration.identity(H, W), seed=5)
    rng = np.random.default_rng(5)
    r = (350.0 + rng.normal(0.0, 3.0, (H, W))).astype(np.float32)
    r[:, :10] += 20.0           # a 20 mm step: inside the 30 mm gate, so it is mixed
    a = np.full((H, W), 50.0, np.float32)
    _constant_head(model, 0.0, -3.0)
    out = correct(model, r, a).range_mm
    inner = out[5:-5, 15:-5]
    # the mean of 25 pixels of 3 mm noise: 3 / 5 = 0.6 mm
    assert 0.45 < inner.std() < 0.75 and abs(inner.mean() - 350.0) < 0.2
    # the pixels next to the 20 mm step take part of it
    assert 3.0 < np.median(out[5:-5, 10] - r[5:-5, 10]) < 10.0
    # a kernel that trusts only the centre returns the pixel's own range
    centre = np.full(25, -30.0)
    centre[12] = 30.0
    _constant_head(model, 0.0, -3.0, centre)
    np.testing.assert_allclose(correct(model, r, a).range_mm, r, atol=1e-3)


def _kernel_case(k: int, channels_last: bool, seed: int = 0
                 ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Logits, ranges (m) and validity of two 23 x 31 frames: a plane with 2 mm noise and two
    steps, one inside the 30 mm gate (12 mm) and one beyond it (80 mm), some invalid pixels."""
    gen = torch.Generator().manual_seed(seed)
    logits = 3.0 * torch.randn(2, k * k, 23, 31, generator=gen)
    if channels_last:
        logits = logits.contiguous(memory_format=torch.channels_last)
    r_mm = 400.0 + 2.0 * torch.randn(2, 23, 31, generator=gen)
    r_mm[:, :, 10:] += 12.0
    r_mm[:, 14:, :] += 80.0
    valid = (torch.rand(2, 23, 31, generator=gen) > 0.1).float()
    return logits, r_mm / 1000.0 * valid, valid


@pytest.mark.parametrize(("k", "channels_last"), [(5, True), (5, False), (3, True)])
def test_kernel_mean_shift_matches_the_per_neighbour_reference(k: int,
                                                               channels_last: bool) -> None:
    logits, range_m, valid = _kernel_case(k, channels_last)
    want = kernel_mean_shift_reference(logits, range_m, valid, 30.0)
    for fn in (kernel_mean_shift, _kernel_mean_shift_torch):
        got = fn(logits, range_m, valid, 30.0)
        assert got.shape == valid.shape and got.dtype == torch.float32
        np.testing.assert_allclose(got.numpy(), want.numpy(), atol=2e-4)
    # a weighted mean of neighbours within the gate moves no pixel beyond it (the 80 mm step
    # takes no weight), and an invalid pixel not at all
    assert 10.0 < float(want.abs().max()) <= 30.0 and (want[valid == 0] == 0).all()
    near_step = want[:, 2:12, 10]             # just right of the 12 mm step, above the 80 mm
    assert float(near_step.mean()) < -0.5     # its left neighbours pull it down


def test_kernel_mean_shift_gradient_matches_the_reference() -> None:
    logits, range_m, valid = _kernel_case(5, channels_last=True, seed=1)
    upstream = torch.randn(valid.shape, generator=torch.Generator().manual_seed(2))
    grads = []
    for fn in (kernel_mean_shift, kernel_mean_shift_reference):
        lg = logits.clone().requires_grad_(True)
        (fn(lg, range_m, valid, 30.0) * upstream).sum().backward()
        grads.append(lg.grad.double())
    np.testing.assert_allclose(grads[0].numpy(), grads[1].numpy(), atol=1e-4)
    assert float(grads[1].abs().max()) > 0.1      # not a vacuous match of zeros
    # invalid pixels pass no gradient to their logits
    assert (grads[0].permute(1, 0, 2, 3)[:, valid == 0] == 0).all()


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


def test_inputs_are_relative_to_the_frame_except_the_absolute_planes() -> None:
    rng = np.random.default_rng(4)
    r = rng.uniform(250, 450, (1, H, W)).astype(np.float32)
    a = rng.uniform(10, 90, (1, H, W)).astype(np.float32)
    x0, valid = fcn_inputs(r, a, 16)
    x1, _ = fcn_inputs(r + 100, a * 7, 16)
    assert x0.shape == (1, 6, 64, 80) and valid.all()
    torch.testing.assert_close(x0[:, [0, 2, 3, 5]], x1[:, [0, 2, 3, 5]], atol=1e-4, rtol=0)
    torch.testing.assert_close(x1[0, 1, :H, :W] - x0[0, 1, :H, :W],
                               torch.full((H, W), 0.1), atol=1e-5, rtol=0)
    torch.testing.assert_close(x1[0, 4, :H, :W] - x0[0, 4, :H, :W],
                               torch.full((H, W), math.log(7) / LOG_AMPLITUDE_SCALE),
                               atol=1e-5, rtol=0)
    # the padding mirrors the last rows and columns (a band of zeros is what training
    # never shows the network)
    torch.testing.assert_close(x0[0, :, H:, :], x0[0, :, H - 15:H - 1, :].flip(1), atol=0,
                               rtol=0)
    torch.testing.assert_close(x0[0, :, :, W:], x0[0, :, :, W - 11:W - 1].flip(2), atol=0,
                               rtol=0)


def test_padding_of_a_tiny_frame_repeats_its_edge() -> None:
    """A side shorter than its padding cannot be mirrored: the edge pixels are repeated."""
    x = torch.arange(12, dtype=torch.float32).reshape(1, 1, 3, 4)
    padded = pad_to_multiple(x, 16)
    assert padded.shape == (1, 1, 16, 16)
    torch.testing.assert_close(padded[0, 0, 15, 15], x[0, 0, 2, 3])
    torch.testing.assert_close(padded[0, 0, :3, 4:], x[0, 0, :, 3:].expand(3, 12))


def test_kernel_takes_no_neighbour_from_the_padding() -> None:
    """Equal weights on a ramp of 2 mm per column: a column with its two neighbours on each
    side in the frame keeps its range; the last column, with two on one side only, moves by
    the mean of (-4, -2, 0) = -2 mm, as on a training crop's border. Mirrored neighbours in
    the kernel would give (-4 - 2 + 0 - 2 - 4) / 5 = -2.4 mm."""
    model = FCNCorrectionModel.untrained(IntrinsicCalibration.identity(H, W), seed=7)
    r = np.tile(300.0 + 2.0 * np.arange(W, dtype=np.float32), (H, 1))
    a = np.full((H, W), 50.0, np.float32)
    _constant_head(model, 0.0, -3.0)
    shift = correct(model, r, a).range_mm - r
    np.testing.assert_allclose(shift[:, 2:-2], 0.0, atol=1e-3)
    np.testing.assert_allclose(shift[:, -1], -2.0, atol=1e-3)
    np.testing.assert_allclose(shift[:, 0], 2.0, atol=1e-3)


def test_local_detail_is_the_range_less_its_neighbours_mean_clipped() -> None:
    r = np.full((1, H, W), 400.0, np.float32)
    r[0, 20, 30] = 410.0        # a 10 mm bump: 10 - 10 / 48 above the mean of its 48 valid
    r[0, 40, 40] = 600.0        # a 200 mm spike: clipped to 50 mm
    r[0, 20, 32] = np.nan       # an invalid pixel is 0 and not in its neighbours' mean
    x, _ = fcn_inputs(r, np.full((1, H, W), 50.0, np.float32), 16)
    detail = x[0, 5].numpy() * DETAIL_CLIP_MM
    assert detail[20, 30] == pytest.approx(10.0 - 10.0 / 48, abs=1e-3)
    assert detail[40, 40] == pytest.approx(50.0) and detail[20, 32] == 0.0
    assert detail[5, 5] == pytest.approx(0.0, abs=1e-4)


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
    with pytest.raises(InputError, match="kernel_px"):
        FCNArchitecture(kernel_px=4)
    with pytest.raises(InputError):
        FCNArchitecture(kernel_gate_mm=0.0)
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


def _resolve_slow(range_mm, sure, unsure):
    """Reference: pixel by pixel, the sure 8-neighbour nearest in range."""
    out = np.where(sure, range_mm, np.nan)
    hs, ws = range_mm.shape[1:]
    for b, y, x in zip(*np.nonzero(unsure), strict=True):
        best, dist = np.nan, np.inf
        for v in range(max(y - 1, 0), min(y + 2, hs)):
            for u in range(max(x - 1, 0), min(x + 2, ws)):
                d = abs(range_mm[b, v, u] - range_mm[b, y, x])
                if sure[b, v, u] and d < dist:
                    best, dist = range_mm[b, v, u], d
        out[b, y, x] = best
    return out


def test_a_flying_pixel_takes_the_nearer_side() -> None:
    from tof_mpd_ros.correction.fcn import resolve_to_a_side
    r = np.full((1, 5, 6), 300.0, np.float32)
    r[:, :, 3:] = 400.0
    r[0, :, 2] = [330.0, 380.0, 330.0, 380.0, 350.0]  # a column of flying pixels
    sure = np.ones(r.shape, bool)
    sure[0, :, 2] = False
    out = resolve_to_a_side(r, sure, ~sure)
    np.testing.assert_array_equal(out[0, :4, 2], [300.0, 400.0, 300.0, 400.0])
    assert out[0, 4, 2] in (300.0, 400.0)      # a tie takes one side, never the mix
    np.testing.assert_array_equal(out[sure], r[sure])
    # no sure neighbour: invalid; neither sure nor unsure: invalid
    alone = resolve_to_a_side(r, np.zeros(r.shape, bool), np.eye(5, 6, dtype=bool)[None])
    assert np.isnan(alone).all()


def test_resolving_matches_the_slow_reference() -> None:
    from tof_mpd_ros.correction.fcn import resolve_to_a_side
    rng = np.random.default_rng(4)
    r = rng.uniform(250, 450, (2, 9, 11)).astype(np.float32)
    r[rng.random(r.shape) < 0.1] = np.nan
    state = rng.integers(0, 3, r.shape)              # 0 sure, 1 unsure, 2 neither
    sure, unsure = (state == 0) & np.isfinite(r), (state == 1) & np.isfinite(r)
    np.testing.assert_array_equal(resolve_to_a_side(r, sure, unsure),
                                  _resolve_slow(r, sure, unsure).astype(np.float32))
