"""Every named effect: switches off cleanly (bit-exact), is deterministic, and does what its
docstring says, with numbers."""

from __future__ import annotations

import numpy as np
import pytest
from oracles.analytic_scenes import box_on_table_scene, plane_scene, raycast

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.sim.tof import (
    EFFECTS,
    CameraMotion,
    ToFConfig,
    phase_per_mm,
    render_from_reference,
    render_tof,
)
from tof_mpd_ros.sim.tof.effects.pixel_offset import offset_pattern
from tof_mpd_ros.sim.tof.effects.temperature_drift import drift_mm
from tof_mpd_ros.sim.tof.effects.wiggling import wiggle_mm

K = Intrinsics.ds325().crop(60, 48)
SCENE = box_on_table_scene(300.0, 80.0, 15.0, 0.5, box_albedo=0.3)
MOTION = CameraMotion(linear_mm_s=(200.0, 0.0, 0.0), angular_rad_s=(0.0, 0.2, 0.0))
#: parameters that make each effect visible on SCENE
ACTIVE = {
    "multipath": {"gain": 1.5}, "mixed_pixels": {"psf_sigma_px": 0.8},
    "wiggling": {"a1_mm": 4.0}, "amplitude_bias": {"bias_mm": 4.0},
    "pixel_offset": {"offset_std_mm": 3.0}, "noise": {"read_std": 1.0},
    "phase_wrapping": {}, "lens_scatter": {"fraction": 0.05},
    "subsurface": {"delay_mm": [1.0, 6.0]}, "temperature_drift": {"max_mm": 8.0},
    "time_offset": {"offset_ms": 20.0}, "hand_eye": {"rx_mrad": 5.0, "tz_mm": 2.0},
    "noise_model": {"scale": 2.0, "jitter_mm": 1.0},
}


def _render(config: ToFConfig, seed: int = 7, frame_index: int = 30, s: int = 1):
    surf = raycast(SCENE, K.scaled(s) if s > 1 else K)
    return render_tof(surf, config, np.random.default_rng(seed), supersample=s,
                      frame_index=frame_index, motion=MOTION)


def _same(a, b) -> bool:
    return (np.array_equal(a.range_mm, b.range_mm, equal_nan=True)
            and np.array_equal(a.amplitude, b.amplitude, equal_nan=True))


def test_every_effect_has_parameters_for_all_names():
    assert set(ACTIVE) == set(EFFECTS)


@pytest.fixture(scope="module")
def nominal():
    return _render(ToFConfig.nominal())


@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_effect_switches_off_bit_exactly(name, nominal):
    base = ToFConfig.nominal()
    on = base.with_effect(name, enabled=True, **ACTIVE[name])
    off = on.with_effect(name, enabled=False)  # non-default parameters, switched off
    if not base.enabled(name):
        assert _same(_render(off), nominal)
    else:
        reference = _render(base.with_effect(name, enabled=False))
        assert _same(_render(off), reference)


@pytest.mark.parametrize("name", sorted(set(EFFECTS) - {"phase_wrapping"}))
def test_effect_changes_the_measurement_and_is_deterministic(name, nominal):
    cfg = ToFConfig.nominal().with_effect(name, enabled=True, **ACTIVE[name])
    first = _render(cfg)
    assert _same(first, _render(cfg))
    changed = ~np.isclose(first.range_mm, nominal.range_mm, atol=1e-3, equal_nan=True)
    assert changed.mean() > 0.02, name


def test_different_seeds_give_different_noise():
    a = _render(ToFConfig.nominal(), seed=1)
    b = _render(ToFConfig.nominal(), seed=2)
    assert not np.array_equal(a.range_mm, b.range_mm, equal_nan=True)


def _plane_cfg(*names: str, **params) -> ToFConfig:
    cfg = ToFConfig.ideal()
    for n in names:
        cfg = cfg.with_effect(n, enabled=True, **params.get(n, {}))
    return cfg


def _plane(cfg: ToFConfig, frame_index: int = 0, distance: float = 300.0, albedo: float = 0.5):
    surf = raycast(plane_scene(distance, albedo), K)
    return surf.range_mm, render_tof(surf, cfg, np.random.default_rng(0), supersample=1,
                                     frame_index=frame_index)


def test_temperature_drift_grows_with_frame_index():
    cfg = _plane_cfg("temperature_drift")
    p = cfg.params("temperature_drift")
    errs = [float(np.mean(m.range_mm - t)) for t, m in
            (_plane(cfg, frame_index=n) for n in (0, 100, 1000))]
    assert errs[0] == pytest.approx(0.0, abs=1e-4)
    assert errs[1] == pytest.approx(p["max_mm"] * (1 - np.exp(-1)), abs=1e-3)
    assert errs[2] == pytest.approx(drift_mm(1000, p["max_mm"], p["tau_frames"]), abs=1e-3)


def test_wiggling_is_the_documented_harmonic_error():
    cfg = _plane_cfg("wiggling")
    p = cfg.params("wiggling")
    for d in (180.0, 300.0, 420.0):
        truth, m = _plane(cfg, distance=d)
        expected = wiggle_mm(truth, cfg.mod_freq_hz, p["a1_mm"], p["p1_rad"], p["a2_mm"],
                             p["p2_rad"])
        np.testing.assert_allclose(m.range_mm - truth, expected, atol=1e-4)
        assert float(np.max(np.abs(expected))) <= p["a1_mm"] + p["a2_mm"]


def test_amplitude_bias_grows_for_dim_pixels():
    cfg = _plane_cfg("amplitude_bias")
    t_bright, bright = _plane(cfg, albedo=0.9)
    t_dark, dark = _plane(cfg, albedo=0.05)
    assert float(np.mean(dark.range_mm - t_dark)) > float(np.mean(bright.range_mm - t_bright)) + 3


def test_pixel_offset_is_a_fixed_pattern():
    cfg = _plane_cfg("pixel_offset")
    p = cfg.params("pixel_offset")
    t1, a = _plane(cfg, distance=250.0)
    t2, b = _plane(cfg, distance=400.0)
    e1, e2 = a.range_mm - t1, b.range_mm - t2
    # the same pixels are high at both distances: offset pattern, plus a gain in r
    assert float(np.corrcoef(e1.ravel(), e2.ravel())[0, 1]) > 0.9
    assert float(np.mean(e1)) == pytest.approx(p["offset_mean_mm"], abs=0.5)
    assert float(np.std(e1)) == pytest.approx(np.hypot(p["offset_std_mm"],
                                                       250 * p["gain_std"]), rel=0.1)


def test_lens_scatter_pulls_dim_far_pixels_towards_bright_near_ones():
    cfg = _plane_cfg("lens_scatter")
    surf = raycast(SCENE, K)
    clean = render_tof(surf, ToFConfig.ideal(), np.random.default_rng(0), supersample=1)
    glare = render_tof(surf, cfg, np.random.default_rng(0), supersample=1)
    table = surf.object_id == 0
    top = (surf.object_id == 1) & (surf.normal[..., 2] < -0.9)
    # the bright near box top pulls table pixels closer; the table pulls the top farther
    assert float(np.mean((glare.range_mm - clean.range_mm)[table])) < -0.05
    assert float(np.mean((glare.range_mm - clean.range_mm)[top])) > 0.05


def test_subsurface_delays_each_material_by_its_own_amount():
    cfg = _plane_cfg("subsurface", subsurface={"delay_mm": [0.0, 6.0], "fraction": [0.5, 0.5],
                                               "sigma_px": [0.0, 0.0]})
    surf = raycast(SCENE, K)
    m = render_tof(surf, cfg, np.random.default_rng(0), supersample=1)
    err = m.range_mm - surf.range_mm
    # half the light 6 mm late: the phasor-mean range moves by ≈ 3 mm on material 1 only
    np.testing.assert_allclose(err[surf.material_id == 0], 0.0, atol=1e-4)
    assert float(np.median(err[surf.material_id == 1])) == pytest.approx(3.0, abs=0.05)


def test_time_offset_shifts_the_image_with_camera_motion():
    cfg = _plane_cfg("time_offset", time_offset={"offset_ms": 20.0})
    surf = raycast(SCENE, K)
    still = render_tof(surf, cfg, np.random.default_rng(0), supersample=1)
    np.testing.assert_array_equal(still.range_mm, surf.range_mm.astype(np.float32))
    moving = CameraMotion(linear_mm_s=(0.0, 0.0, -250.0))  # backing away at 250 mm/s
    m = render_tof(surf, cfg, np.random.default_rng(0), supersample=1, motion=moving)
    table = (surf.object_id == 0) & (m.true_range_mm > 0)
    # 20 ms later the camera is 5 mm farther: the table reads ≈ 5 mm farther along the axis
    centre = table[K.height // 2 - 3:K.height // 2 + 3, :10]
    diff = (m.range_mm - surf.range_mm)[K.height // 2 - 3:K.height // 2 + 3, :10][centre]
    assert float(np.median(diff)) == pytest.approx(5.0, abs=0.8)


def test_hand_eye_rotation_shifts_the_image_by_f_times_angle():
    cfg = _plane_cfg("hand_eye", hand_eye={"ry_mrad": 10.0})
    surf = raycast(SCENE, K)
    m = render_tof(surf, cfg, np.random.default_rng(0), supersample=1)
    # turning the camera by +10 mrad about y (towards +x) moves image content by −fx·0.01 px
    expected = -K.fx * 0.01
    rows = slice(K.height // 2 - 5, K.height // 2 + 5)
    before = np.argmax(surf.range_mm[rows] < 260, axis=1)
    after = np.argmax(m.true_range_mm[rows] < 260, axis=1)
    assert abs(float(np.mean(after - before)) - expected) <= 1.0


def test_noise_model_scales_the_noise():
    nominal = _plane_cfg("noise")
    scaled = nominal.with_effect("noise_model", enabled=True, scale=2.0)
    t, a = _plane(nominal)
    _, b = _plane(scaled)
    assert float(np.std(b.range_mm - t)) / float(np.std(a.range_mm - t)) == pytest.approx(
        2.0, rel=0.1)


def test_render_from_reference_is_deterministic_and_nominal_by_default():
    ref = raycast(SCENE, K).range_mm
    a = render_from_reference(ref, K, rng=np.random.default_rng(3))
    b = render_from_reference(ref, K, config=ToFConfig.nominal(), rng=np.random.default_rng(3))
    assert _same(a, b)
    c = render_from_reference(ref, K)
    assert _same(c, render_from_reference(ref, K))
    assert phase_per_mm(30e6) == pytest.approx(4 * np.pi * 30e6 / 299792458e3)


def test_pixel_offset_pattern_belongs_to_sensor_pixels_not_to_the_crop():
    sensor = Intrinsics.ds325()
    full, _ = offset_pattern(sensor, 7, 4.0, 2.0, 0.005)
    crop, _ = offset_pattern(sensor.crop(180, 140), 7, 4.0, 2.0, 0.005)
    window, _ = offset_pattern(sensor.crop(204, 164), 7, 4.0, 2.0, 0.005)
    rows, cols = sensor.crop_window(180, 140)
    np.testing.assert_array_equal(crop, full[rows, cols])
    np.testing.assert_array_equal(crop, window[12:-12, 12:-12])
    other, _ = offset_pattern(sensor, 8, 4.0, 2.0, 0.005)
    assert abs(float(np.corrcoef(full.ravel(), other.ravel())[0, 1])) < 0.02
    assert float(np.std(full)) == pytest.approx(2.0, rel=0.02)
