"""AMCW ToF physics with numbers: direct return, amplitude law, phase wrapping, mixed pixels,
noise scaling (docs/physics.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from oracles.analytic_scenes import box, half_space, plane_scene, raycast

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.sim.tof import (
    ToFConfig,
    ambiguity_range_mm,
    render_from_reference,
    render_tof,
)
from tof_mpd_ros.sim.tof.effects.noise import range_noise_std_mm

K = Intrinsics.ds325().crop(180, 140)
SMALL = Intrinsics.from_fov(64, 48, 74.0)
DIRECT = ToFConfig.ideal()


def _render(scene, config, *, k=SMALL, s=1, seed=0):
    return render_tof(raycast(scene, k.scaled(s) if s > 1 else k), config,
                      np.random.default_rng(seed), supersample=s)


def test_direct_only_plane_reads_true_range():
    scene = plane_scene(300.0, tilt_rad=0.4)
    m = _render(scene, DIRECT, k=K)
    truth = raycast(scene, K).range_mm
    err = m.range_mm - truth
    assert np.all(np.isfinite(err))
    # exact up to the float32 output (≈ 3e-5 mm at 300 mm)
    assert abs(float(np.mean(err))) < 1e-4 and float(np.max(np.abs(err))) < 1e-4


def test_direct_plane_with_pixel_footprint_reads_true_range():
    scene = plane_scene(300.0, tilt_rad=0.4)
    m = _render(scene, DIRECT.with_effect("mixed_pixels", enabled=True), k=K, s=3)
    truth = raycast(scene, K).range_mm
    # the footprint averages phasors over a tilted patch: unbiased to well under 0.1 mm
    assert abs(float(np.nanmean(m.range_mm - truth))) < 0.1


def test_amplitude_follows_albedo_cos_over_r_squared():
    cfg = DIRECT
    base = _render(plane_scene(300.0, 0.5), cfg)
    dark = _render(plane_scene(300.0, 0.25), cfg)
    far = _render(plane_scene(600.0, 0.5), cfg)
    tilted = _render(plane_scene(300.0, 0.5, tilt_rad=math.radians(45)), cfg)
    c = (24, 32)
    np.testing.assert_allclose(dark.amplitude[c] / base.amplitude[c], 0.5, rtol=1e-6)
    # same ray, range doubled: a ∝ 1/r²
    np.testing.assert_allclose(base.amplitude[c] / far.amplitude[c],
                               (far.range_mm[c] / base.range_mm[c]) ** 2, rtol=1e-5)
    # every pixel: a = P ρ cosθ / r² with θ from the exact plane normal
    surf = raycast(plane_scene(300.0, 0.5, tilt_rad=math.radians(45)), SMALL)
    cos = -np.einsum("hwk,hwk->hw", surf.normal, SMALL.ray_directions())
    expected = cfg.light_power * 0.5 * cos / surf.range_mm ** 2
    valid = expected >= cfg.min_amplitude  # dimmer pixels fall below the floor: NaN
    np.testing.assert_array_equal(np.isfinite(tilted.amplitude), valid)
    np.testing.assert_allclose(tilted.amplitude[valid], expected[valid], rtol=1e-5)
    assert float(np.min(cos)) < 0.2 and float(np.max(cos)) > 0.9


def test_default_frequency_does_not_wrap_in_workspace():
    amb = ambiguity_range_mm(ToFConfig().mod_freq_hz)
    assert amb == pytest.approx(299792458e3 / 60e6) and amb > 450.0 * 5


@pytest.mark.parametrize("distance", [300.0, 420.0])
def test_phase_wraps_at_ambiguity_range(distance):
    cfg = DIRECT.with_effect("phase_wrapping", enabled=True)
    cfg = ToFConfig.from_dict({**cfg.to_dict(), "mod_freq_hz": 750e6})  # c/2f ≈ 199.9 mm
    amb = ambiguity_range_mm(750e6)
    m = _render(plane_scene(distance), cfg)
    truth = raycast(plane_scene(distance), SMALL).range_mm
    np.testing.assert_allclose(m.range_mm, truth - amb * np.floor(truth / amb), atol=1e-4)
    assert float(np.nanmax(m.range_mm)) < amb
    unwrapped = _render(plane_scene(distance), cfg.with_effect("phase_wrapping", enabled=False))
    np.testing.assert_allclose(unwrapped.range_mm, truth, atol=1e-4)


def _step_scene():
    # a box centred on the axis: its top (z = 200) ends in depth edges over the table (z = 300)
    return [half_space((0.0, 0.0, -1.0), (0.0, 0.0, 300.0)),
            box((-25.0, -25.0, 200.0), (25.0, 25.0, 301.0))]


def test_mixed_pixels_lie_between_foreground_and_background():
    cfg = DIRECT.with_effect("mixed_pixels", enabled=True, psf_sigma_px=0.0)
    m = _render(_step_scene(), cfg, s=3)
    centre = raycast(_step_scene(), SMALL).range_mm
    fg = float(np.nanmax(np.where(centre < 250, centre, np.nan)))
    bg = float(np.nanmin(np.where(centre > 250, centre, np.nan)))
    between = (m.range_mm > fg + 5.0) & (m.range_mm < bg - 5.0)
    assert between.sum() >= 8  # the edge pixels of the box outline
    assert np.nanmin(m.range_mm) > 199.0 and np.nanmax(m.range_mm) < 301.0 / 0.7
    # without the footprint every pixel reads one surface: none in between
    off = _render(_step_scene(), DIRECT, s=3)
    assert not np.any((off.range_mm > fg + 5.0) & (off.range_mm < bg - 5.0))


def test_mixed_pixels_from_reference_mix_neighbours():
    ref = raycast(_step_scene(), SMALL).range_mm
    cfg = DIRECT.with_effect("mixed_pixels", enabled=True)
    m = render_from_reference(ref, SMALL, config=cfg)
    # foreground pixels next to the edge are pulled back, background ones pulled forward
    fg_edge = (ref < 250) & (np.abs(m.range_mm - ref) > 1.0)
    bg_edge = (ref > 250) & (np.abs(m.range_mm - ref) > 1.0)
    assert fg_edge.sum() >= 8 and bg_edge.sum() >= 8
    assert np.all(m.range_mm[fg_edge] > ref[fg_edge])
    assert np.all(m.range_mm[bg_edge] < ref[bg_edge])


@pytest.mark.parametrize("albedo", [0.5, 0.05])
def test_noise_std_follows_amplitude_law(albedo):
    cfg = DIRECT.with_effect("noise", enabled=True)
    scene = plane_scene(300.0, albedo)
    truth = raycast(scene, K).range_mm
    clean = _render(scene, DIRECT, k=K)
    stds = []
    for seed in range(4):
        m = _render(scene, cfg, k=K, seed=seed)
        p = cfg.params("noise")
        sigma = range_noise_std_mm(clean.amplitude.astype(np.float64), cfg.mod_freq_hz,
                                   p["read_std"], p["shot_gain"], p["ambient"])
        stds.append(np.std((m.range_mm - truth) / sigma))
    # normalised error has unit std over ~10^5 pixel draws
    assert float(np.mean(stds)) == pytest.approx(1.0, abs=0.03)


def test_noise_std_grows_as_amplitude_falls():
    cfg = DIRECT.with_effect("noise", enabled=True)
    bright = _render(plane_scene(300.0, 0.8), cfg, k=K)
    dark = _render(plane_scene(300.0, 0.04), cfg, k=K)
    truth = raycast(plane_scene(300.0), K).range_mm
    s_bright = float(np.std(bright.range_mm - truth))
    s_dark = float(np.std(dark.range_mm - truth))
    p = cfg.params("noise")
    a_b, a_d = float(np.median(bright.amplitude)), float(np.median(dark.amplitude))
    predicted = (range_noise_std_mm(a_d, cfg.mod_freq_hz, p["read_std"], p["shot_gain"])
                 / range_noise_std_mm(a_b, cfg.mod_freq_hz, p["read_std"], p["shot_gain"]))
    assert s_dark / s_bright == pytest.approx(float(predicted), rel=0.05)
    assert s_dark / s_bright > 5.0  # 20x less light: between sqrt(20) (shot) and 20 (read)
    assert 1.0 < s_bright < 3.0  # a few mm at 300 mm, ρ = 0.8


def test_amplitude_floor_invalidates_dim_pixels():
    cfg = DIRECT.with_effect("noise", enabled=True)
    far = _render(plane_scene(300.0, 0.001), cfg)  # amplitude ≈ 1.1 < floor 5
    assert np.all(np.isnan(far.range_mm)) and np.all(np.isnan(far.amplitude))
