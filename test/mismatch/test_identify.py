"""Each effect is identified on a small concealed case, and the control is answered ``none``.

The cases are analytic sweeps (see conftest): supersampled "real" renders, a noisy reference,
a camera sliding at varying speed. Only the first greedy round runs (``max_effects=1``) to keep
the default test time down; the two-effect search is exercised by the slow test and the
benchmark.
"""

from __future__ import annotations

import pytest

from tof_mpd_ros.mismatch import analyse

# effect -> (concealed parameters, parameter to check, tolerance)
CASES = {
    "multipath": ({"gain": 2.5}, "gain", 0.8),
    "temperature_drift": ({"max_mm": 8.0, "tau_frames": 5.0}, "max_mm", 3.0),
    "time_offset": ({"offset_ms": 40.0}, "offset_ms", 10.0),
    "noise_model": ({"scale": 2.5}, "scale", 0.8),
    "lens_scatter": ({"fraction": 0.06, "sigma_px": 15.0}, "fraction", 0.03),
    "wiggling": ({"a1_mm": 8.0, "p1_rad": -2.0}, "a1_mm", 3.0),
    "amplitude_bias": ({"bias_mm": -8.0, "exponent": 1.0}, "bias_mm", 4.0),
    "mixed_pixels": ({"psf_sigma_px": 1.3}, "psf_sigma_px", 0.5),
    "subsurface": ({"delay_mm": (10.0,), "fraction": (0.5,), "sigma_px": (2.0,)}, None, None),
    "pixel_offset": ({"offset_std_mm": 8.0, "gain_std": 0.02}, "offset_std_mm", 3.0),
    "hand_eye": ({"rx_mrad": 8.0, "tz_mm": 4.0, "tx_mm": 3.0}, "tz_mm", 2.5),
}
FAST = ("multipath", "temperature_drift", "time_offset", "noise_model")


def _check(sweep, effect: str) -> None:
    params, key, tol = CASES[effect]
    result = analyse(sweep({effect: params}), max_effects=1)
    assert result.selected == [effect], [(r.effect, round(r.score, 1)) for r in result.rounds[0]]
    if key is not None:
        assert abs(result.parameters[effect][key] - params[key]) < tol, result.parameters
    assert result.metrics["interior_excess_rmse_after_mm"] <= \
        result.metrics["interior_excess_rmse_before_mm"] + 1e-9


def test_control_is_none(sweep):
    result = analyse(sweep({}), max_effects=1)
    assert result.selected == []
    assert all(r.score <= 5.0 or r.t_stat <= 3.0 for r in result.rounds[0])


@pytest.mark.parametrize("effect", FAST)
def test_effect_is_identified(sweep, effect):
    _check(sweep, effect)


@pytest.mark.slow
@pytest.mark.parametrize("effect", [e for e in CASES if e not in FAST])
def test_effect_is_identified_slow(sweep, effect):
    _check(sweep, effect)


@pytest.mark.slow
def test_two_effects_are_both_found(sweep):
    frames = sweep({"multipath": {"gain": 2.5}, "temperature_drift": {"max_mm": 8.0,
                                                                     "tau_frames": 5.0}})
    result = analyse(frames, max_effects=2)
    assert set(result.selected) == {"multipath", "temperature_drift"}
