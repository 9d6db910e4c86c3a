"""The pipeline's one step list, typed effect parameters, and registering a new effect."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import toy_effects
from oracles.analytic_scenes import box_on_table_scene, raycast

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.sim.tof import (
    DIRECT,
    EFFECTS,
    STAGE_ORDER,
    Action,
    ToFConfig,
    pipeline_steps,
    register_effect,
    render_from_reference,
    render_tof,
    unregister_effect,
)

K = Intrinsics.ds325().crop(40, 32)
SCENE = box_on_table_scene(300.0, 80.0, 15.0, 0.5, box_albedo=0.3)


class ToyOffset(toy_effects.ToyOffset):
    """The tests' toy offset under a name of this module's own."""

    name = "toy_offset_sim"


@pytest.fixture
def toy():
    effect = register_effect(ToyOffset, after="wiggling")
    yield effect
    unregister_effect(ToyOffset.name)


def test_steps_follow_the_stage_order_with_every_effect_once():
    steps = pipeline_steps()
    assert [s.name for s in steps if s.effect is not None] == sorted(
        EFFECTS, key=lambda n: STAGE_ORDER.index(EFFECTS[n].stage))
    ranks = [STAGE_ORDER.index(s.stage) for s in steps]
    assert ranks == sorted(ranks)
    assert [s.name for s in steps if s.effect is None] == [DIRECT]
    assert steps[len(tuple(n for n in EFFECTS if EFFECTS[n].stage == "geometry"))].name == DIRECT


def test_noise_model_stands_in_for_noise():
    noise = next(s for s in pipeline_steps() if s.name == "noise")
    cfg = ToFConfig.nominal()
    assert noise.action(cfg) is Action.APPLY
    assert noise.action(cfg.with_effect("noise_model", enabled=True)) is Action.SKIP
    assert noise.action(cfg.with_effect("noise", enabled=False)) is Action.BYPASS


@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_parameters_are_one_typed_dataclass_per_effect(name):
    effect = EFFECTS[name]
    names = [f.name for f in dataclasses.fields(effect.Params)]
    assert [p.name for p in effect.params] == names
    typed = ToFConfig.nominal().effect_params(name)
    assert isinstance(typed, effect.Params) and typed == effect.Params()
    with pytest.raises(dataclasses.FrozenInstanceError):
        typed.x = 1.0  # type: ignore[attr-defined]
    assert dataclasses.asdict(typed) == effect.defaults()


def test_a_registered_effect_is_rendered_where_it_was_registered(toy):
    assert list(EFFECTS).index(toy.name) == list(EFFECTS).index("wiggling") + 1
    cfg = ToFConfig.nominal().with_effect("noise", enabled=False)
    on = cfg.with_effect(toy.name, enabled=True, offset_mm=2.5)
    surf = raycast(SCENE, K.scaled(3))
    a = render_tof(surf, cfg, np.random.default_rng(0), supersample=3)
    b = render_tof(surf, on, np.random.default_rng(0), supersample=3)
    # after wiggling (which depends on the range), before pixel_offset's gain (1 + g)·r
    g = b.range_mm - a.range_mm
    assert float(np.nanmedian(g)) == pytest.approx(2.5, abs=0.05)
    ref = raycast(SCENE, K).range_mm
    c = render_from_reference(ref, K, 0.5, cfg)
    d = render_from_reference(ref, K, 0.5, on)
    assert float(np.nanmedian(d.range_mm - c.range_mm)) == pytest.approx(2.5, abs=0.05)
    off = on.with_effect(toy.name, enabled=False)
    assert np.array_equal(render_tof(surf, off, np.random.default_rng(0), supersample=3).range_mm,
                          a.range_mm, equal_nan=True)


def test_registering_checks_its_input(toy):
    with pytest.raises(ValueError, match="already registered"):
        register_effect(ToyOffset)
    with pytest.raises(ValueError, match="not a registered range effect"):
        register_effect(type("Other", (ToyOffset,), {"name": "other"}), after="multipath")
    with pytest.raises(ValueError, match="not an added effect"):
        unregister_effect("multipath")
    assert "other" not in EFFECTS


def test_an_unregistered_effect_is_gone():
    register_effect(ToyOffset)
    assert list(EFFECTS)[-1] == ToyOffset.name  # last of the last stage
    unregister_effect(ToyOffset.name)
    assert ToyOffset.name not in EFFECTS
    assert ToyOffset.name not in {s.name for s in pipeline_steps()}
