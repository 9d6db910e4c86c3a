"""The stream corrector (what the corrector node runs) with a model of the fcn kind: the depth is
``correct``'s, the confidence image is the predicted σ in metres (in the output's convention),
the edge map is empty, and the patch kind's geodesic knobs are refused by name.

Plain numpy (no ROS); ``test/nodes/test_corrector_outputs.py`` checks the published messages.
"""

from __future__ import annotations

import numpy as np
import pytest

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.correction import fcn_onnx
from tof_mpd_ros.correction.depth_stream import DepthStreamCorrector, confidence_image
from tof_mpd_ros.correction.fcn import FCNCorrectionModel
from tof_mpd_ros.correction.pipeline import CorrectionModel, GeodesicParams, correct
from tof_mpd_ros.errors import InputError

H, W = 24, 32            # the model's window
FH, FW = 30, 40          # the frames': the window is rows 3..27, columns 4..36
K = Intrinsics(fx=40.0, fy=52.0, cx=19.25, cy=14.5, width=FW, height=FH)
CROP = (slice(3, 27), slice(4, 36))


def _frame() -> tuple[np.ndarray, np.ndarray]:
    """(FH, FW) float32 depth in mm (a tilted plane with a 60 mm step) and amplitude, one NaN
    depth and one zero amplitude inside the window."""
    v, u = np.mgrid[0:FH, 0:FW]
    depth = (420.0 + 2.0 * u + 1.0 * v - 60.0 * (u >= 20)).astype(np.float32)
    amplitude = (300.0 + 2.0 * v).astype(np.float32)
    depth[8, 10] = np.nan
    amplitude[12, 25] = 0.0
    return depth, amplitude


@pytest.fixture(scope="module")
def model() -> FCNCorrectionModel:
    """An untrained fcn model whose ``max_sigma_mm`` is the median σ it predicts on the
    window of :func:`_frame` (so about half the pixels are dropped for their σ)."""
    m = FCNCorrectionModel.untrained(IntrinsicCalibration.identity(H, W), seed=5)
    depth, amplitude = _frame()
    m.max_sigma_mm = float(np.nanmedian(correct(m, depth[CROP], amplitude[CROP]).sigma_mm))
    return m


def test_radial_confidence_is_sigma_in_metres_of_correct(model: FCNCorrectionModel) -> None:
    depth, amplitude = _frame()
    out = DepthStreamCorrector(model, input_convention="radial", threads=1).correct(
        depth, amplitude, K)
    expected = correct(model, depth[CROP], amplitude[CROP])
    np.testing.assert_allclose(out.depth_mm, expected.range_mm, rtol=1e-6, equal_nan=True)
    np.testing.assert_allclose(out.sigma_mm, expected.sigma_mm, rtol=1e-6, equal_nan=True)
    conf = confidence_image(out)
    assert conf.dtype == np.float32 and conf.shape == (H, W)
    np.testing.assert_allclose(conf, expected.sigma_mm / 1000.0, rtol=1e-6, atol=0,
                               equal_nan=True)
    # NaN exactly on the invalid inputs; millimetres of σ, i.e. a few thousandths of a metre
    invalid = ~expected.valid
    assert invalid.sum() == 2 and np.isnan(conf[invalid]).all()
    assert np.isfinite(conf[~invalid]).all()
    assert 1e-4 < np.nanmin(conf) and np.nanmax(conf) < 0.05
    assert not out.edges.any()
    # σ above max_sigma_mm: the depth is a sure neighbour's or dropped, the confidence image
    # still says why
    unsure = expected.valid & (expected.sigma_mm > model.max_sigma_mm)
    assert unsure.any() and (~unsure & expected.valid).any()
    taken = out.depth_mm[unsure]
    assert np.isnan(taken).any() and np.isfinite(taken).any()
    assert np.isin(taken[np.isfinite(taken)], out.depth_mm[~unsure & expected.valid]).all()
    assert np.isfinite(conf[unsure]).all()


def test_z_confidence_is_the_sigma_of_the_z_depth(model: FCNCorrectionModel) -> None:
    """z = r · (z / r) per pixel: the z-depth's σ is the radial σ times the same factor."""
    depth, amplitude = _frame()
    crop_k = K.crop(W, H)
    out = DepthStreamCorrector(model, input_convention="z", threads=1).correct(
        depth, amplitude, K)
    expected = correct(model, crop_k.z_to_radial(depth[CROP]), amplitude[CROP])
    factor = crop_k.z_per_radial()
    assert factor.min() < 0.99  # off-axis pixels: the factor is not 1
    np.testing.assert_allclose(confidence_image(out), expected.sigma_mm * factor / 1000.0,
                               rtol=1e-5, equal_nan=True)
    np.testing.assert_allclose(out.depth_mm, expected.range_mm * factor, rtol=1e-5,
                               equal_nan=True)


def test_patch_kind_confidence_is_unchanged_and_geodesic_knobs_refuse_fcn(
        model: FCNCorrectionModel) -> None:
    depth, amplitude = _frame()
    patch = CorrectionModel.untrained(IntrinsicCalibration.identity(H, W), seed=3)
    out = DepthStreamCorrector(patch, threads=1).correct(depth, amplitude, K)
    assert out.sigma_mm is None and confidence_image(out) is out.confidence
    assert 0.0 <= out.confidence.min() and out.confidence.max() <= 1.0
    with pytest.raises(InputError, match="patch kind only; this model is of kind 'fcn'"):
        DepthStreamCorrector(model, geodesic=GeodesicParams())
    stream = DepthStreamCorrector(model, threads=1)
    assert stream.geodesic is None and stream.kind == "fcn"
    assert stream.warm_up() >= 0.0


def test_bfloat16_stream_is_correct_in_bfloat16(model: FCNCorrectionModel) -> None:
    depth, amplitude = _frame()
    out = DepthStreamCorrector(model, input_convention="radial", threads=1,
                               precision="bfloat16").correct(depth, amplitude, K)
    bf16 = correct(model, depth[CROP], amplitude[CROP], precision="bfloat16")
    f32 = correct(model, depth[CROP], amplitude[CROP])
    np.testing.assert_allclose(out.sigma_mm, bf16.sigma_mm, rtol=1e-6, equal_nan=True)
    # reduced precision: not float32's bits, but within a millimetre of them here
    ok = np.isfinite(f32.range_f_mm)
    assert not np.array_equal(bf16.sigma_mm[ok], f32.sigma_mm[ok])
    assert np.nanmax(np.abs(bf16.range_f_mm - f32.range_f_mm)) < 1.0
    with pytest.raises(InputError, match="precision"):
        DepthStreamCorrector(model, precision="int8")


@pytest.mark.skipif(not fcn_onnx.available(), reason="onnxruntime and onnx are not installed")
def test_the_stream_runs_the_executor_it_is_given(model: FCNCorrectionModel) -> None:
    """``fcn_engine`` reaches ``correct``: forced to either executor on two threads, the stream
    gives ``correct``'s output under that executor, the two within a micrometre (not bit-equal:
    the arithmetic is ordered differently). A value that cannot run is refused at construction
    for the fcn kind and ignored, if valid, for the patch kind."""
    depth, amplitude = _frame()
    sigmas = {}
    for engine in ("torch", "onnxruntime"):
        stream = DepthStreamCorrector(model, input_convention="radial", threads=2,
                                      fcn_engine=engine)
        out = stream.correct(depth, amplitude, K)
        want = correct(model, depth[CROP], amplitude[CROP], fcn_engine=engine)
        np.testing.assert_allclose(out.depth_mm, want.range_mm, rtol=1e-6, equal_nan=True)
        np.testing.assert_allclose(out.sigma_mm, want.sigma_mm, rtol=1e-6, equal_nan=True)
        sigmas[engine] = out.sigma_mm
    ok = np.isfinite(sigmas["torch"])
    assert np.array_equal(ok, np.isfinite(sigmas["onnxruntime"])) and ok.sum() == H * W - 2
    # σ in mm: equal to float32 rounding, not bit for bit (another order of arithmetic)
    assert 0 < np.abs(sigmas["torch"] - sigmas["onnxruntime"])[ok].max() < 1e-3
    with pytest.raises(InputError, match="float32 only"):
        DepthStreamCorrector(model, precision="bfloat16", fcn_engine="onnxruntime")
    with pytest.raises(InputError, match="fcn_engine must be one of"):
        DepthStreamCorrector(model, fcn_engine="tflite")
    patch = CorrectionModel.untrained(IntrinsicCalibration.identity(H, W), seed=1)
    assert DepthStreamCorrector(patch, precision="int8",
                                fcn_engine="onnxruntime").fcn_engine == "onnxruntime"
