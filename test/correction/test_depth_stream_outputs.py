"""What the corrector's extra outputs are made of: organized points, the correction image, the
crop of the input the stream result carries, and the edge / geodesic knobs a caller overrides.

Plain numpy (no ROS): the node only wraps these in messages.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.correction.depth_stream import DepthStreamCorrector, correction_m, points_m
from tof_mpd_ros.correction.pipeline import CorrectionModel, GeodesicParams, correct
from tof_mpd_ros.errors import InputError

H, W = 24, 32
# Non-square pixels and an off-centre principal point: a swapped fx/fy or cx/cy shows.
K = Intrinsics(fx=40.0, fy=52.0, cx=13.25, cy=9.5, width=W, height=H)


def _depth_mm() -> np.ndarray:
    """(H, W) float32 z-depth in mm, a tilted plane, with a few invalid pixels."""
    v, u = np.mgrid[0:H, 0:W]
    depth = (400.0 + 3.0 * u + 1.5 * v).astype(np.float32)
    depth[2, 5] = np.nan
    depth[10, 0] = np.nan
    return depth


def _model(seed: int = 3) -> CorrectionModel:
    return CorrectionModel.untrained(IntrinsicCalibration.identity(H, W), seed=seed)


def test_points_of_z_depth_follow_the_pinhole_model() -> None:
    depth = _depth_mm()
    pts = points_m(depth, K, "z")
    assert pts.shape == (H, W, 3) and pts.dtype == np.float32
    # z is the depth in metres, within float32 precision; NaN exactly where the depth is.
    invalid = np.isnan(depth)
    np.testing.assert_array_equal(np.isnan(pts), np.repeat(invalid[..., None], 3, axis=2))
    np.testing.assert_allclose(pts[..., 2][~invalid], depth[~invalid] / 1000.0, rtol=1e-6)
    # One pixel by hand: u = 20, v = 7, z = 400 + 60 + 10.5 = 470.5 mm.
    u, v, z = 20, 7, 0.4705
    assert pts[v, u, 2] == pytest.approx(z, rel=1e-6)
    assert pts[v, u, 0] == pytest.approx((u - 13.25) * z / 40.0, rel=1e-6)   # x right
    assert pts[v, u, 1] == pytest.approx((v - 9.5) * z / 52.0, rel=1e-6)     # y down
    # Left of and above the principal point: negative x and y (REP 103 optical frame).
    assert pts[0, 0, 0] < 0 and pts[0, 0, 1] < 0 and pts[H - 1, W - 1, 0] > 0


def test_points_of_radial_range_lie_at_that_distance_along_the_pixel_ray() -> None:
    radial = _depth_mm()
    pts = points_m(radial, K, "radial")
    valid = ~np.isnan(radial)
    np.testing.assert_allclose(np.linalg.norm(pts, axis=2)[valid], radial[valid] / 1000.0,
                               rtol=1e-6)
    u, v = 30, 1
    x, y, z = pts[v, u]
    assert x / z == pytest.approx((u - 13.25) / 40.0, rel=1e-6)
    assert y / z == pytest.approx((v - 9.5) / 52.0, rel=1e-6)
    # The same surface as z-depth is nearer along the axis than its radial range.
    assert z < radial[v, u] / 1000.0


def test_z_radial_conversion_is_the_ray_cosine_computed_once_per_camera() -> None:
    """The cosine is cached per camera (equal intrinsics share it, read-only); the conversions
    equal the exact per-call formula, and another camera gets its own rays."""
    from tof_mpd_ros.camera import Intrinsics

    k = Intrinsics.from_fov(64, 48, 60.0)
    cos = k.ray_directions()[..., 2]
    depth = np.random.default_rng(1).uniform(300, 900, (48, 64)).astype(np.float32)
    np.testing.assert_array_equal(k.z_to_radial(depth), (depth / cos).astype(np.float32))
    np.testing.assert_array_equal(k.radial_to_z(depth), (depth * cos).astype(np.float32))
    same = Intrinsics.from_fov(64, 48, 60.0)
    assert same.z_per_radial() is k.z_per_radial() and not k.z_per_radial().flags.writeable
    wide = Intrinsics.from_fov(64, 48, 90.0)
    assert wide.z_per_radial().min() < k.z_per_radial().min() - 0.05
    np.testing.assert_array_equal(wide.z_per_radial(), wide.ray_directions()[..., 2])


def test_points_refuse_a_wrong_size_or_convention() -> None:
    with pytest.raises(InputError):
        points_m(np.ones((H + 1, W), np.float32), K, "z")
    with pytest.raises(InputError, match="convention"):
        points_m(np.ones((H, W), np.float32), K, "depth")


def test_correction_is_corrected_minus_input_in_metres_nan_where_either_is_invalid() -> None:
    corrected = np.array([[500.0, np.nan, 610.0], [700.0, 800.5, np.nan]], np.float32)
    measured = np.array([[510.0, 600.0, np.nan], [700.0, 800.0, np.nan]], np.float32)
    out = correction_m(corrected, measured)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(np.isnan(out), [[False, True, True], [False, False, True]])
    np.testing.assert_allclose(out[0, 0], -0.010, atol=1e-7)
    np.testing.assert_allclose(out[1, 0], 0.0, atol=0)
    np.testing.assert_allclose(out[1, 1], 0.0005, atol=1e-7)
    with pytest.raises(InputError):
        correction_m(corrected, measured[:, :2])


def test_stream_result_carries_the_input_crop_and_its_convention() -> None:
    """Input larger than the model's window: input_mm and amplitude are the same central
    crop as the corrected depth, the input's invalid pixels (0, negative, NaN) NaN."""
    full = Intrinsics(fx=40.0, fy=52.0, cx=20.0, cy=14.0, width=W + 10, height=H + 7)
    v, u = np.mgrid[0:full.height, 0:full.width]
    depth = (450.0 + 2.0 * u - 1.0 * v).astype(np.float32)
    amplitude = (300.0 + 5.0 * v).astype(np.float32)
    rows, cols = full.crop_window(W, H)
    depth[rows.start + 1, cols.start + 2] = 0.0
    depth[rows.start + 3, cols.start + 4] = -5.0
    depth[rows.start + 5, cols.start + 6] = np.nan
    for convention in ("z", "radial"):
        result = DepthStreamCorrector(_model(), input_convention=convention,
                                      threads=1).correct(depth, amplitude, full)
        assert result.convention == convention
        assert result.intrinsics == full.crop(W, H)
        expected = depth[rows, cols].copy()
        expected[expected <= 0] = np.nan
        np.testing.assert_array_equal(result.input_mm, expected)
        np.testing.assert_array_equal(result.amplitude, amplitude[rows, cols])
        assert result.input_mm.dtype == result.amplitude.dtype == np.float32
        assert np.isnan(result.depth_mm[1, 2]) and np.isnan(result.depth_mm[3, 4])


def test_geodesic_override_equals_a_model_carrying_those_constants() -> None:
    """``correct(..., geodesic=g)`` is the model with ``g`` inside, on every output; the
    thresholds reach the edge map (0.99 finds no edge of an untrained G, 0.0 every maximum)."""
    model = _model()
    v, u = np.mgrid[0:H, 0:W]
    range_mm = (400.0 + 2.0 * u + 0.5 * v).astype(np.float32)
    range_mm[:, W // 2:] += 80.0   # a depth step
    amplitude = np.full((H, W), 900.0, np.float32)
    maps = {}
    for low, high, k, sigma in ((0.99, 0.99, 81, 2.0), (0.0, 0.0, 25, 4.0)):
        g = GeodesicParams(k=k, sigma=sigma, edge_low=low, edge_high=high)
        got = correct(model, range_mm, amplitude, geodesic=g)
        want = correct(dataclasses.replace(model, geodesic=g), range_mm, amplitude)
        for name in ("range_mm", "edges", "confidence"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), name)
        maps[high] = got.edges
    assert not maps[0.99].any() and maps[0.0].sum() > 10
    # The stream corrector passes its own geodesic on, and keeps the model's by default.
    stream = DepthStreamCorrector(model, threads=1)
    assert stream.geodesic == model.geodesic
    g = GeodesicParams(edge_low=0.0, edge_high=0.0)
    k = Intrinsics.from_fov(W, H, 60.0)
    edges = DepthStreamCorrector(model, input_convention="radial", threads=1,
                                 geodesic=g).correct(range_mm, amplitude, k).edges
    np.testing.assert_array_equal(edges, maps[0.0])
