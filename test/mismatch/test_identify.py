"""Each effect is identified on a small concealed case, and the control is answered ``none``.

The cases are analytic sweeps (see conftest): supersampled "real" renders, a noisy reference,
a camera sliding at varying speed. Only the first greedy round runs (``max_effects=1``) to keep
the default test time down; the two-effect search is exercised by the slow test and the
benchmark.
"""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.mismatch import analyse
from tof_mpd_ros.mismatch.analysis import rank
from tof_mpd_ros.mismatch.fit import CANDIDATES, FitResult
from tof_mpd_ros.mismatch.predict import noise_std_mm
from tof_mpd_ros.mismatch.profile import CAMERA_WINDOWS, PROFILE_EFFECTS
from tof_mpd_ros.sim.tof import ToFConfig

NOMINAL = ToFConfig.nominal()

def _drift_at_frame5(p: dict) -> float:
    return p["max_mm"] * (1.0 - math.exp(-5.0 / p["tau_frames"]))


def _noise_ratio(result) -> float:
    a = np.array([200.0])
    return float(noise_std_mm(a, result.config_after)[0] / noise_std_mm(a, NOMINAL)[0])


# effect -> (concealed parameters, check(fitted parameters, analysis) -> bool)
CASES = {
    "multipath": ({"gain": 3.0}, lambda p, r: p["gain"] > 1.6),
    "temperature_drift": ({"max_mm": 8.0, "tau_frames": 5.0},
                          lambda p, r: abs(_drift_at_frame5(p) - 8.0 * (1 - math.exp(-1))) < 2),
    "time_offset": ({"offset_ms": 40.0}, lambda p, r: 15.0 < p["offset_ms"] < 60.0),
    "noise_model": ({"scale": 2.5}, lambda p, r: 1.8 < _noise_ratio(r) < 3.2),
    "lens_scatter": ({"fraction": 0.06, "sigma_px": 15.0},
                     lambda p, r: abs(p["fraction"] - 0.06) < 0.03),
    "wiggling": ({"a1_mm": 8.0, "p1_rad": -2.0}, lambda p, r: True),
    "amplitude_bias": ({"bias_mm": -8.0, "exponent": 1.0}, lambda p, r: p["bias_mm"] < -3.0),
    "mixed_pixels": ({"psf_sigma_px": 1.3}, lambda p, r: abs(p["psf_sigma_px"] - 1.3) < 0.5),
    "subsurface": ({"delay_mm": (10.0,), "fraction": (0.5,), "sigma_px": (2.0,)},
                   lambda p, r: True),
    "pixel_offset": ({"offset_std_mm": 8.0, "gain_std": 0.02},
                     lambda p, r: abs(p["offset_std_mm"] - 8.0) < 3.0),
    "hand_eye": ({"rx_mrad": 8.0, "tz_mm": 4.0, "tx_mm": 3.0},
                 lambda p, r: abs(p["tz_mm"] - 4.0) < 2.0),
}
FAST = ("temperature_drift", "time_offset", "noise_model")


#: interreflection near one crease needs more pixels than 48 x 36 to stand out of the noise
LARGER = {"multipath": {"intrinsics": Intrinsics.from_fov(80, 60, 74.0)}}


def _check(sweep, effect: str) -> None:
    """A camera effect is found as the camera's profile and nothing is named on top; a scene,
    pose or timing effect is named on top of an empty profile."""
    params, check = CASES[effect]
    result = analyse(sweep({effect: params}, **LARGER.get(effect, {})), max_effects=1)
    rounds = [[(r.effect, round(r.score, 1)) for r in rnd] for rnd in result.rounds]
    if effect in PROFILE_EFFECTS:
        assert result.profile[:1] == [effect] and result.selected == [], rounds
    else:
        assert result.profile == [] and result.selected == [effect], rounds
    assert check(result.parameters[effect], result), result.parameters
    assert result.metrics["interior_excess_rmse_after_mm"] <= \
        result.metrics["interior_excess_rmse_before_mm"] + 1e-9


def test_control_is_none(sweep):
    result = analyse(sweep({}), max_effects=1)
    assert result.selected == [] and result.profile == [] and result.unexplained == []
    # one round for the camera's profile, one for what it has its own value of within a
    # window (the albedo's interreflection, the lens's blur), one for the physics on top:
    # nothing significant
    assert [sorted(r.effect for r in rnd) for rnd in result.rounds[1:2]] == [
        sorted(CAMERA_WINDOWS)]
    assert len(result.rounds) == 3
    assert all(r.score <= 5.0 or r.t_stat <= 3.0 for rnd in result.rounds for r in rnd)
    # and the evidence still ranks every candidate
    assert {r.effect for rnd in result.rounds for r in rnd} == set(CANDIDATES)
    # the nominal camera's amplitude is in the simulator's units: the grey world keeps them
    assert result.profile_facts["amplitude_scale"] == pytest.approx(1.0, abs=0.3)


@pytest.mark.parametrize("effect", FAST)
def test_effect_is_identified(sweep, effect):
    _check(sweep, effect)


#: measured on the three-bounce world transport (issue 12): the tripled indirect light is ranked
#: first but its held-out t is 2.9, under MIN_T; issue 13 reworks the tool on the new physics
_KNOWN_MISSES = {"multipath": "issue 13: held-out t 2.9 < MIN_T on the multi-bounce physics"}


@pytest.mark.slow
@pytest.mark.parametrize("effect", [
    pytest.param(e, marks=pytest.mark.xfail(strict=True, reason=_KNOWN_MISSES[e]))
    if e in _KNOWN_MISSES else e for e in CASES if e not in FAST])
def test_effect_is_identified_slow(sweep, effect):
    _check(sweep, effect)


@pytest.mark.slow
def test_two_effects_are_both_found(sweep):
    frames = sweep({"lens_scatter": {"fraction": 0.06, "sigma_px": 15.0},
                    "temperature_drift": {"max_mm": 8.0, "tau_frames": 5.0}})
    result = analyse(frames, max_effects=2)
    assert set(result.selected) == {"lens_scatter", "temperature_drift"}


def test_subsurface_without_delay_yields_to_mixed_pixels():
    cfg = NOMINAL
    blur = FitResult("subsurface", cfg, {"delay_mm": 0.5, "sigma_px": 1.1, "fraction": 0.9}, 3,
                     score=100.0)
    delayed = FitResult("subsurface", cfg, {"delay_mm": 9.0, "sigma_px": 1.1, "fraction": 0.4},
                        3, score=100.0)
    mixed = FitResult("mixed_pixels", cfg, {"psf_sigma_px": 1.1}, 1, score=97.0)
    assert rank([blur, mixed])[0].effect == "mixed_pixels"
    # with a real delay the richer physics stays (no held-out data: parsimony alone decides,
    # and a 3 % lead with no paired test keeps the simpler one)
    assert rank([delayed, FitResult("mixed_pixels", cfg, {}, 1, score=50.0)])[0] is delayed


def _at_one_pose(frames: list) -> list:
    """The sweep's first frame, held: the camera at the same pose in every frame (new stamps)."""
    return [dataclasses.replace(frames[0], stamp_ns=f.stamp_ns) for f in frames]


def test_camera_moves_needs_a_pose_difference(sweep):
    from tof_mpd_ros.mismatch.fit import AT_REST_MM, camera_moves

    frames = sweep({})
    held = _at_one_pose(frames)
    assert camera_moves([SimpleNamespace(frame=f) for f in frames])
    assert not camera_moves([SimpleNamespace(frame=f) for f in held])
    # a shift just under the tolerance is rest, just over it is motion
    for shift_mm, moves in ((0.9 * AT_REST_MM, False), (1.5 * AT_REST_MM, True)):
        pose = held[1].pose.copy()
        pose[2, 3] += shift_mm * 1e-3
        nudged = [held[0], dataclasses.replace(held[1], pose=pose)]
        assert camera_moves([SimpleNamespace(frame=f) for f in nudged]) is moves
    assert not camera_moves([SimpleNamespace(frame=dataclasses.replace(f, pose=None))
                             for f in frames])


def test_hand_eye_is_not_named_at_one_pose(sweep):
    """A hand–eye error seen from one pose is a constant misregistration of ToF against the
    reference, which the reference's own registration produces as well: not named. On the
    moving sweep the same error is fitted, near its true pose."""
    params = CASES["hand_eye"][0]
    held = analyse(_at_one_pose(sweep({"hand_eye": params})), candidates=("hand_eye",),
                   max_effects=1)
    assert held.selected == []
    (only,) = held.rounds[-1]
    assert only.effect == "hand_eye" and "same pose" in only.note
    moving = analyse(sweep({"hand_eye": params}), candidates=("hand_eye",), max_effects=1)
    (fitted,) = moving.rounds[-1]
    assert fitted.note == ""
    assert abs(fitted.parameters["rx_mrad"] - params["rx_mrad"]) < 2.0
    assert abs(fitted.parameters["tx_mm"] - params["tx_mm"]) < 1.5


def test_a_lens_blur_beyond_the_cameras_window_is_named_with_all_of_it(sweep):
    """A 1.0 px blur: the camera's profile takes the lens window at its 0.6 px limit, and the
    scene round names the blur judged against the window released, so it is credited with
    the whole blur (scoring over twice the window's share, not only the remainder beyond
    0.6 px) and is no longer the profile's (session 39, ``profile_s122/1``)."""
    analysis = analyse(sweep({"mixed_pixels": {"psf_sigma_px": 1.0}}))
    fits = [(k, r) for k, rnd in enumerate(analysis.rounds) for r in rnd
            if r.effect == "mixed_pixels"]
    (k_window, window), (k_scene, scene) = fits[0], fits[-1]
    assert k_window < k_scene
    assert window.parameters["psf_sigma_px"] == pytest.approx(CAMERA_WINDOWS["mixed_pixels"][2])
    assert analysis.selected == ["mixed_pixels"]
    assert scene.score > 2.0 * window.score
    assert 0.75 < analysis.parameters["mixed_pixels"]["psf_sigma_px"] < 1.25
    assert "mixed_pixels" not in analysis.profile
