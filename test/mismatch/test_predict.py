"""The staged predictor: equal to the simulator's render, sub-pixel moves, hole filling, albedo."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.mismatch.predict import (
    FramePredictor,
    fill_holes,
    infer_albedo,
    noise_std_mm,
)
from tof_mpd_ros.pose import rotvec_to_matrix
from tof_mpd_ros.sim.tof import ToFConfig, render_from_reference, render_tof
from tof_mpd_ros.sim.tof.analytic import box_on_table_scene, plane_scene, raycast
from tof_mpd_ros.sim.tof.effects.noise import range_noise_std_mm

K = Intrinsics.from_fov(40, 30, 74.0)
QUIET = ToFConfig.nominal().with_effect("noise", enabled=False)


@pytest.fixture(scope="module")
def box_frame() -> tuple[ToFFrame, np.ndarray]:
    ref = raycast(box_on_table_scene(), K).range_mm
    meas = render_from_reference(ref, K, 0.5, QUIET)
    return ToFFrame(meas.range_mm, meas.amplitude, K, reference_mm=ref), ref


@pytest.mark.parametrize("name,params", [
    ("multipath", {"gain": 2.0}), ("lens_scatter", {"enabled": True, "fraction": 0.05}),
    ("wiggling", {"a1_mm": 6.0}), ("subsurface", {"enabled": True}),
    ("temperature_drift", {"enabled": True}), ("mixed_pixels", {"psf_sigma_px": 1.0}),
    ("amplitude_bias", {"bias_mm": -5.0}),
])
def test_predictor_equals_simulator_render(box_frame, name, params):
    frame, _ref = box_frame
    pred = FramePredictor(frame, QUIET, frame_index=7, albedo=np.full(K.shape, 0.5))
    cfg = QUIET.with_effect(name, **params)
    ours = pred.predict(cfg)
    # the same float32 reference the predictor reads from the frame
    sim = render_from_reference(frame.reference_mm, K, 0.5, cfg, frame_index=7)
    assert np.array_equal(np.isfinite(ours.range_mm), np.isfinite(sim.range_mm))
    np.testing.assert_allclose(ours.range_mm, sim.range_mm, atol=1e-3, equal_nan=True)
    np.testing.assert_allclose(ours.amplitude, sim.amplitude, rtol=1e-4, equal_nan=True)
    # the effect changed something: the comparison is not vacuous
    assert np.nanmax(np.abs(ours.range_mm - pred.predict().range_mm)) > 0.1


@pytest.mark.parametrize("move", [{"ry_mrad": 8.0}, {"tz_mm": 4.0},
                                  {"rx_mrad": 6.0, "ty_mm": 2.0}])
def test_pose_error_prediction_matches_a_moved_camera(move):
    """hand_eye through the sub-pixel phasor warp vs a supersampled render from the moved
    camera: closer than no move and than the simulator's nearest-pixel warp. (A lateral
    translation alone is not in the list: its parallax at depth edges is sub-pixel structure the
    one-sample-per-pixel reference cannot resolve, and there the prediction is no better.)
    Multipath is off: its world is inferred from each image, which differs between a
    supersampled render and a one-sample reference by more than the move does."""
    quiet = QUIET.with_effect("multipath", enabled=False)
    solids = box_on_table_scene()
    rot = rotvec_to_matrix(1e-3 * np.array([move.get(f"r{a}_mrad", 0.0) for a in "xyz"]))
    t = np.array([move.get(f"t{a}_mm", 0.0) for a in "xyz"])
    moved = [replace(s, normals=s.normals @ rot, offsets=s.offsets - s.normals @ t)
             for s in solids]
    truth = render_tof(raycast(moved, K.scaled(3)), quiet, np.random.default_rng(0),
                       supersample=3).range_mm
    ref = raycast(solids, K)
    still = render_tof(raycast(solids, K.scaled(3)), quiet, np.random.default_rng(0),
                       supersample=3)
    albedo = np.where(ref.object_id == 1, 0.5, 0.5)
    frame = ToFFrame(still.range_mm, still.amplitude, K, reference_mm=ref.range_mm)
    pred = FramePredictor(frame, quiet, albedo=albedo)
    cfg = quiet.with_effect("hand_eye", enabled=True, **move)
    ours = np.nanmean(np.abs(pred.predict(cfg).range_mm - truth))
    none = np.nanmean(np.abs(pred.predict().range_mm - truth))
    sim = np.nanmean(np.abs(render_from_reference(ref.range_mm, K, albedo, cfg).range_mm - truth))
    assert ours < 0.8 * none and ours < sim


def test_fill_holes_fills_from_background():
    ref = np.full((20, 20), 400.0)
    ref[5:9, 5:9] = 300.0  # a foreground block
    ref[5:9, 9:13] = np.nan  # its occlusion shadow
    filled = fill_holes(ref)
    assert np.isfinite(filled).all()
    np.testing.assert_allclose(filled[5:9, 10:13], 400.0)  # background, not the block


def test_infer_albedo_recovers_a_plane():
    surf = raycast(plane_scene(350.0, albedo=0.3, tilt_rad=0.3), K)
    meas = render_from_reference(surf.range_mm, K, 0.3, QUIET.with_only("mixed_pixels"))
    frame = ToFFrame(meas.range_mm, meas.amplitude, K, reference_mm=surf.range_mm)
    rho = infer_albedo(frame, QUIET)
    np.testing.assert_allclose(np.median(rho), 0.3, rtol=0.02)


def test_noise_std_follows_the_noise_law():
    a = np.array([[20.0, 200.0, 2000.0]])
    p = QUIET.params("noise")
    expected = range_noise_std_mm(a, 30e6, p["read_std"], p["shot_gain"], p["ambient"])
    np.testing.assert_allclose(noise_std_mm(a, ToFConfig.nominal()), expected, rtol=1e-6)
    scaled = ToFConfig.nominal().with_effect("noise_model", enabled=True, scale=2.0)
    np.testing.assert_allclose(noise_std_mm(a, scaled), 2 * expected, rtol=1e-6)
