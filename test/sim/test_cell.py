"""The assembled simulated cell: captures, determinism, and calibration against its own errors."""

from __future__ import annotations

import numpy as np
import pytest
from sim_helpers import looking_down, small_camera

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.errors import SimulationError
from tof_mpd_ros.pose import make_pose
from tof_mpd_ros.sim.cell import CameraModel, SimCell
from tof_mpd_ros.sim.checkerboard import CheckerboardConfig, calibration_poses
from tof_mpd_ros.sim.scene import make_box_scene
from tof_mpd_ros.sim.tof import ToFConfig


def test_capture_has_crop_shape_reference_and_pose() -> None:
    scene = make_box_scene()
    cell = SimCell(camera=small_camera())
    frame = cell.capture(scene, looking_down(400.0), np.random.default_rng(0), stamp_ns=7)
    assert frame.range_mm.shape == (36, 48) and frame.intrinsics.shape == (36, 48)
    assert frame.stamp_ns == 7 and frame.pose[2, 3] == pytest.approx(0.4)
    assert np.isfinite(frame.reference_mm).mean() > 0.8
    # The raw ToF deviates from the reference by a few mm (systematic + multipath + noise).
    error = np.nanmedian(np.abs(frame.range_mm - frame.reference_mm))
    assert 0.5 < error < 30.0


def test_capture_is_deterministic_for_a_seed() -> None:
    scene = make_box_scene()
    cell = SimCell(camera=small_camera())
    a = cell.capture(scene, looking_down(350.0), np.random.default_rng(3))
    b = cell.capture(scene, looking_down(350.0), np.random.default_rng(3))
    np.testing.assert_array_equal(a.range_mm, b.range_mm)
    np.testing.assert_array_equal(a.reference_mm, b.reference_mm)


def test_crop_must_fit_the_sensor_but_its_margin_may_reach_past_it() -> None:
    sensor = Intrinsics.from_fov(100, 80, 74.0)
    with pytest.raises(SimulationError, match="does not fit"):
        CameraModel(sensor=sensor, crop=(102, 70), margin_px=4)
    with pytest.raises(SimulationError, match="margin"):
        CameraModel(sensor=sensor, crop=(96, 70), margin_px=-1)
    # a window inside the sensor is the sensor's own central window
    assert CameraModel(sensor=sensor, crop=(60, 40), margin_px=4).window == sensor.crop(68, 48)
    # the whole sensor: a virtual border of 4 px on every side, same focal length and centre
    window = CameraModel(sensor=sensor, crop=(100, 80), margin_px=4).window
    assert (window.width, window.height) == (108, 88)
    assert (window.fx, window.cx - 4, window.cy - 4) == (sensor.fx, sensor.cx, sensor.cy)


def test_a_full_sensor_capture_covers_every_pixel() -> None:
    camera = small_camera()
    full = CameraModel(sensor=camera.sensor, crop=(camera.sensor.width, camera.sensor.height),
                       margin_px=4, supersample=1)
    frame = SimCell(camera=full).capture(make_box_scene(), looking_down(400.0),
                                         np.random.default_rng(0))
    assert frame.range_mm.shape == (90, 120) and frame.intrinsics == camera.sensor
    border = np.ones((90, 120), bool)
    border[4:-4, 4:-4] = False
    # the sensor's outermost pixels are measured and referenced like the rest
    assert np.isfinite(frame.range_mm[border]).mean() > 0.95
    error = np.nanmedian(np.abs(frame.range_mm - frame.reference_mm)[border])
    assert 0.5 < error < 30.0


def test_per_pixel_calibration_removes_most_systematic_error_on_a_plane() -> None:
    """Issue 3: the paper's per-pixel linear calibration, fitted on graded-checkerboard captures,
    cuts the systematic error on a plane by >= 80 % RMSE."""
    camera = small_camera()
    board = CheckerboardConfig(square_mm=120.0)  # big enough to fill the small view
    cell = SimCell(camera=camera)
    rng = np.random.default_rng(11)
    poses = calibration_poses(300, rng)
    captures = [cell.capture_checkerboard(p, rng, board=board) for p in poses]
    calibration = IntrinsicCalibration.fit(np.stack([c.range_mm for c in captures]),
                                           np.stack([c.amplitude for c in captures]),
                                           np.stack([c.reference_mm for c in captures]))

    quiet = SimCell(camera=camera, tof=ToFConfig.nominal().with_effect("noise", enabled=False))
    errors_raw, errors_cal = [], []
    for distance, tilt in ((220.0, 0.0), (330.0, 0.35)):
        plane = make_pose(np.array([[1.0, 0, 0], [0, np.cos(tilt), -np.sin(tilt)],
                                    [0, np.sin(tilt), np.cos(tilt)]]),
                          np.array([0.0, 0.0, distance]))
        frame = quiet.capture_checkerboard(plane, np.random.default_rng(0), board=board)
        corrected = calibration.apply(frame.range_mm, frame.amplitude)
        errors_raw.append(frame.range_mm - frame.reference_mm)
        errors_cal.append(corrected - frame.reference_mm)
    rmse_raw = np.sqrt(np.nanmean(np.square(errors_raw)))
    rmse_cal = np.sqrt(np.nanmean(np.square(errors_cal)))
    assert rmse_raw > 3.0, "the nominal cell should carry mm-scale systematic errors"
    assert rmse_cal < 0.2 * rmse_raw, (rmse_raw, rmse_cal)
