"""The staged predictor: equal to the simulator's render, sub-pixel moves, hole filling, albedo."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest
from oracles.analytic_scenes import box_on_table_scene, plane_scene, raycast
from toy_effects import ToyOffset

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.mismatch import predict as predict_module
from tof_mpd_ros.mismatch.predict import (
    FramePredictor,
    fill_holes,
    infer_albedo,
    noise_std_mm,
)
from tof_mpd_ros.pose import rotvec_to_matrix
from tof_mpd_ros.sim.tof import (
    EFFECTS,
    CameraMotion,
    Effect,
    ToFConfig,
    param,
    phase_per_mm,
    pipeline_steps,
    register_effect,
    render_from_reference,
    render_tof,
    unregister_effect,
)
from tof_mpd_ros.sim.tof import render as render_module
from tof_mpd_ros.sim.tof.effects.noise import range_noise_std_mm

K = Intrinsics.from_fov(40, 30, 74.0)
QUIET = ToFConfig.nominal().with_effect("noise", enabled=False)
MOTION = CameraMotion(linear_mm_s=(150.0, 0.0, -40.0), angular_rad_s=(0.0, 0.1, 0.0))


@dataclass(frozen=True)
class ToyDelayParams:
    delay_mm: float = param(2.0, 0.0, 10.0, "mm", "extra path of every return")


class ToyDelay(Effect):
    """A phasor-stage effect known only to this test: every return comes ``delay_mm`` late."""

    name = "toy_delay"
    stage = "phasor"
    Params = ToyDelayParams

    def apply(self, x: np.ndarray, params: ToyDelayParams, ctx) -> np.ndarray:
        return x * np.exp(1j * phase_per_mm(ctx.mod_freq_hz) * params.delay_mm)


@pytest.fixture
def toys():
    """The two toy effects registered (the delay right after multipath, the offset last)."""
    register_effect(ToyDelay, after="multipath")
    register_effect(ToyOffset)
    yield
    unregister_effect(ToyDelay.name)
    unregister_effect(ToyOffset.name)


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


def test_rebased_predictor_reuses_the_frame_surface_and_predicts_like_a_fresh_one(box_frame):
    # rebasing happens after every named effect: the surface and its normals (a plane fit per
    # pixel) depend on the frame only, so they are shared, and nothing else may change
    frame, _ref = box_frame
    albedo = np.full(K.shape, 0.5)
    pred = FramePredictor(frame, QUIET, albedo=albedo)
    cfg = QUIET.with_effect("mixed_pixels", enabled=True, psf_sigma_px=0.8) \
        .with_effect("wiggling", enabled=True, a1_mm=3.0)
    rebased = pred.rebased(cfg)
    assert rebased.surface is pred.surface
    fresh = FramePredictor(frame, cfg, albedo=albedo)
    for config in (None, cfg.with_effect("pixel_offset", enabled=True, offset_mean_mm=2.0)):
        np.testing.assert_array_equal(rebased.predict(config).range_mm,
                                      fresh.predict(config).range_mm)
        np.testing.assert_array_equal(rebased.predict(config).amplitude,
                                      fresh.predict(config).amplitude)

def test_predictor_equals_simulator_render_with_every_effect_at_once(box_frame):
    """Effects that do not commute (wiggling reads the range pixel_offset scales; scatter and
    subsurface mix what multipath added): any difference in step order shows."""
    frame, _ref = box_frame
    cfg = (QUIET.with_effect("multipath", gain=2.0)
           .with_effect("lens_scatter", enabled=True, fraction=0.05)
           .with_effect("subsurface", enabled=True)
           .with_effect("temperature_drift", enabled=True)
           .with_effect("mixed_pixels", psf_sigma_px=1.0)
           .with_effect("wiggling", a1_mm=6.0)
           .with_effect("pixel_offset", gain_std=0.05))
    pred = FramePredictor(frame, QUIET, frame_index=7, albedo=np.full(K.shape, 0.5))
    ours = pred.predict(cfg)
    sim = render_from_reference(frame.reference_mm, K, 0.5, cfg, frame_index=7)
    assert np.array_equal(np.isfinite(ours.range_mm), np.isfinite(sim.range_mm))
    np.testing.assert_allclose(ours.range_mm, sim.range_mm, atol=1e-3, equal_nan=True)
    np.testing.assert_allclose(ours.amplitude, sim.amplitude, rtol=1e-4, equal_nan=True)


def test_a_registered_effect_is_applied_by_renderer_and_predictor(box_frame, toys):
    frame, _ref = box_frame
    base = replace(QUIET)  # made again: now it holds the toys (off)
    cfg = (base.with_effect(ToyDelay.name, enabled=True, delay_mm=2.0)
           .with_effect(ToyOffset.name, enabled=True, offset_mm=1.5))
    pred = FramePredictor(frame, base, frame_index=7, albedo=np.full(K.shape, 0.5))
    assert [s.name for s in pred.steps].index(ToyDelay.name) == \
        [s.name for s in pred.steps].index("multipath") + 1
    ours = pred.predict(cfg)
    sim = render_from_reference(frame.reference_mm, K, 0.5, cfg, frame_index=7)
    np.testing.assert_allclose(ours.range_mm, sim.range_mm, atol=1e-3, equal_nan=True)
    # both moved every pixel by the toys' 3.5 mm (wiggling and the pixel gains bend it a little)
    plain = render_from_reference(frame.reference_mm, K, 0.5, base, frame_index=7)
    for moved, before in ((ours.range_mm, pred.predict().range_mm),
                          (sim.range_mm, plain.range_mm)):
        assert float(np.nanmedian(moved - before)) == pytest.approx(3.5, abs=0.1)
    # and a toy that only its base switches on is there too (the predictor's cached states)
    rebased = pred.rebased(cfg)
    np.testing.assert_array_equal(rebased.predict().range_mm, ours.range_mm)


def _recorder(calls: list[str], name: str, method):
    def record(*args, **kwargs):
        calls.append(name)
        return method(*args, **kwargs)
    return record


def _calls_in_order(monkeypatch, run) -> list[str]:
    """Names of the effects (and ``direct``) ``run()`` calls, in order, a name once per run of
    consecutive calls (an effect's apply calls its own helpers)."""
    calls: list[str] = []
    for name, effect in EFFECTS.items():
        for method in ("apply", "bypass", "camera_move", "add_indirect", "scatter"):
            if hasattr(effect, method):
                monkeypatch.setattr(effect, method,
                                    _recorder(calls, name, getattr(effect, method)))
    for module in (render_module, predict_module):
        monkeypatch.setattr(module, "direct_phasor",
                            _recorder(calls, "direct", module.direct_phasor))
    run()
    monkeypatch.undo()
    return [c for i, c in enumerate(calls) if i == 0 or calls[i - 1] != c]


def test_renderer_and_predictor_walk_the_steps_in_the_same_order(box_frame, toys, monkeypatch):
    """Every effect on (the toys too): the order in which the renderer and the predictor run
    them. They differ only by the noise, which the expected value leaves out."""
    frame, _ref = box_frame
    cfg = replace(QUIET)
    for name in EFFECTS:
        cfg = cfg.with_effect(name, enabled=True)
    cfg = cfg.with_effect("time_offset", offset_ms=10.0).with_effect("hand_eye", rx_mrad=2.0)
    rendered = _calls_in_order(monkeypatch, lambda: render_from_reference(
        frame.reference_mm, K, 0.5, cfg, frame_index=7, motion=MOTION))
    predicted = _calls_in_order(monkeypatch, lambda: FramePredictor(
        frame, cfg, frame_index=7, motion=MOTION, albedo=np.full(K.shape, 0.5)))
    noise = {n for n, e in EFFECTS.items() if e.stochastic}
    assert "noise_model" in rendered  # the renderer did run the noise
    assert [c for c in rendered if c not in noise] == predicted
    assert predicted == [s.name for s in pipeline_steps() if s.name not in noise]
    assert {ToyDelay.name, ToyOffset.name, "hand_eye", "time_offset"} <= set(predicted)
