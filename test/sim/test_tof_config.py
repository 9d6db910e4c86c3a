"""ToFConfig, the effect registry and surface_from_reference: API, serialisation, errors."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from oracles.analytic_scenes import groove_scene, plane_scene, raycast

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.errors import InputError, SimulationError
from tof_mpd_ros.sim.tof import (
    EFFECTS,
    NOMINAL_EFFECTS,
    ToFConfig,
    render_from_reference,
    render_tof,
    surface_from_reference,
)

K = Intrinsics.ds325().crop(60, 48)

CANONICAL = {"multipath", "mixed_pixels", "wiggling", "amplitude_bias", "pixel_offset", "noise",
             "phase_wrapping", "lens_scatter", "subsurface", "temperature_drift", "time_offset",
             "hand_eye", "noise_model"}


def test_registry_holds_the_canonical_effects():
    assert set(EFFECTS) == CANONICAL
    assert set(NOMINAL_EFFECTS) == {"multipath", "mixed_pixels", "wiggling", "amplitude_bias",
                                    "pixel_offset", "noise", "phase_wrapping"}
    assert ToFConfig() == ToFConfig.nominal()
    assert set(ToFConfig.nominal().enabled_effects()) == set(NOMINAL_EFFECTS)
    assert ToFConfig.ideal().enabled_effects() == ()


@pytest.mark.parametrize("name", sorted(CANONICAL))
def test_every_parameter_is_documented_with_a_realistic_range(name):
    effect = EFFECTS[name]
    assert effect.summary and effect.stage
    for p in effect.params:
        assert p.doc and p.unit and p.low <= p.high
        for v in np.atleast_1d(p.default):
            assert p.low <= v <= p.high, (name, p.name)


def test_config_round_trips_through_json():
    cfg = (ToFConfig.nominal().with_effect("lens_scatter", enabled=True, fraction=0.03)
           .with_effect("subsurface", enabled=True, delay_mm=[1.0, 2.5])
           .with_effect("multipath", gain=1.2))
    back = ToFConfig.from_dict(json.loads(json.dumps(cfg.to_dict())))
    assert back == cfg
    assert back.params("subsurface")["delay_mm"] == (1.0, 2.5)
    assert back.enabled("lens_scatter") and back.params("multipath")["gain"] == 1.2


def test_with_effect_keeps_state_and_other_effects():
    cfg = ToFConfig.nominal().with_effect("noise", read_std=2.0)
    assert cfg.enabled("noise") and cfg.params("noise")["read_std"] == 2.0
    assert cfg.params("noise")["shot_gain"] == EFFECTS["noise"].defaults()["shot_gain"]
    assert ToFConfig.nominal().params("noise")["read_std"] != 2.0  # the original is unchanged
    only = cfg.with_only("noise")
    assert only.enabled_effects() == ("noise",) and only.params("noise")["read_std"] == 2.0


@pytest.mark.parametrize("bad, match", [
    (lambda: ToFConfig.nominal().with_effect("glare"), "unknown effect 'glare'"),
    (lambda: ToFConfig.nominal().with_effect("noise", sigma=1.0), "no parameter 'sigma'"),
    (lambda: ToFConfig.nominal().with_effect("noise", read_std="big"), "expected a number"),
    (lambda: ToFConfig.nominal().with_effect("noise", read_std=math.nan), "finite"),
    (lambda: ToFConfig(mod_freq_hz=0.0), "mod_freq_hz"),
    (lambda: ToFConfig.from_dict({"colour": 1}), "unknown ToF config keys"),
    (lambda: ToFConfig.from_dict({"effects": {"noise": {"on": True}}}), "enabled, params"),
])
def test_config_errors_are_typed_and_say_what_is_wrong(bad, match):
    with pytest.raises(SimulationError, match=match):
        bad()


def test_partial_dict_switches_the_rest_off():
    cfg = ToFConfig.from_dict({"effects": {"noise": {"enabled": True}}})
    assert cfg.enabled_effects() == ("noise",)


def test_surface_from_reference_normals_and_holes():
    surf = raycast(plane_scene(300.0, tilt_rad=0.5), K)
    ref = surf.range_mm.copy()
    ref[10:14, 20:25] = np.nan
    derived = surface_from_reference(ref, K)
    angle = np.degrees(np.arccos(np.clip(np.einsum("hwk,hwk->hw", derived.normal, surf.normal),
                                         -1, 1)))
    assert float(np.nanmax(angle)) < 1e-3
    assert np.all(np.isnan(derived.range_mm[10:14, 20:25]))
    assert np.all(derived.albedo[derived.valid] == 0.5)
    # the crease of a groove: each side keeps its own plane's normal next to the crease
    g = raycast(groove_scene(), K)
    dg = surface_from_reference(g.range_mm, K)
    off_crease = np.abs(np.arange(K.width) - K.cx) > 3
    dots = np.einsum("hwk,hwk->hw", dg.normal, g.normal)[:, off_crease]
    assert float(np.min(dots)) > 0.999


def test_surface_from_reference_smooths_reference_noise():
    surf = raycast(plane_scene(300.0), K)
    noisy = surf.range_mm + np.random.default_rng(0).normal(0.0, 0.5, K.shape)
    derived = surface_from_reference(noisy, K)
    tilt = np.degrees(np.arccos(np.clip(-derived.normal[..., 2], -1, 1)))
    assert float(np.median(tilt)) < 5.0  # unsmoothed one-sided differences: ~25°


def test_reference_input_errors():
    ref = np.full(K.shape, 300.0)
    with pytest.raises(InputError, match="reference_range_mm"):
        surface_from_reference(ref[:-1], K)
    with pytest.raises(InputError, match="> 0"):
        surface_from_reference(np.zeros(K.shape), K)
    with pytest.raises(InputError, match="albedo"):
        surface_from_reference(ref, K, albedo=1.5)
    with pytest.raises(InputError, match="config"):
        render_from_reference(ref, K, config={"noise": True})


def test_render_tof_input_errors():
    surf = raycast(plane_scene(), K.scaled(2))
    rng = np.random.default_rng(0)
    with pytest.raises(InputError, match="multiple of supersample=7"):
        render_tof(surf, ToFConfig(), rng, supersample=7)
    with pytest.raises(InputError, match="supersample"):
        render_tof(surf, ToFConfig(), rng, supersample=0)
    with pytest.raises(InputError, match="rng"):
        render_tof(surf, ToFConfig(), 0, supersample=2)
    m = render_tof(surf, ToFConfig(), rng, supersample=2)
    assert m.range_mm.shape == K.shape and m.range_mm.dtype == np.float32
    assert m.amplitude.dtype == np.float32 and m.intrinsics == K
    frame = m.to_frame(stamp_ns=5)
    assert frame.range_mm.shape == K.shape and frame.stamp_ns == 5


def test_reference_without_valid_pixels_or_with_isolated_ones():
    k = Intrinsics.from_fov(8, 6, 74.0)
    empty = render_from_reference(np.full(k.shape, np.nan), k)
    assert np.all(np.isnan(empty.range_mm))
    lone = np.where(np.eye(6, 8) > 0, 300.0, np.inf)  # inf counts as missing
    m = render_from_reference(lone, k, config=ToFConfig.ideal())
    np.testing.assert_array_equal(np.isfinite(m.range_mm), np.eye(6, 8) > 0)
    np.testing.assert_allclose(m.range_mm[np.eye(6, 8) > 0], 300.0, atol=1e-4)
