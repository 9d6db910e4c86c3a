"""A warm-up drift is judged on the held-out frames' levels, where its signature is.

On a noisy camera, a drift of a few millimetres over the recording gains little per pixel
(below the score a later greedy round asks), but every frame's level is known to a few tenths
of a millimetre: the drift fitted on the training frames must predict how the held-out
frames' levels move, and a recording without one must not pass.
"""

from __future__ import annotations

import math

import pytest

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.mismatch import analyse
from tof_mpd_ros.mismatch.analysis import MIN_SCORE
from tof_mpd_ros.mismatch.fit import fit_effect
from tof_mpd_ros.mismatch.frame_levels import (
    FRAME_LEVEL_EFFECTS,
    MAX_CHI2_LEFT,
    MIN_CHI2_GAIN,
    FrameLevels,
    frame_levels,
)
from tof_mpd_ros.sim.tof import ToFConfig

#: a camera 3× noisier than the nominal cell, with 3 mm of amplitude-independent jitter
NOISY = ToFConfig.nominal().with_effect("noise_model", enabled=True, scale=3.0, jitter_mm=3.0)
#: 64 × 48 pixels: enough for a frame's level to be known to ~0.7 mm on the noisiest camera
MEDIUM = Intrinsics.from_fov(64, 48, 74.0)
#: a warm-up drift of −4.3 mm over the 6 frames (1.7 mm RMS about its mean)
DRIFT = {"max_mm": -9.0, "tau_frames": 8.0}


def test_frame_level_measures_a_known_offset(sweep, problem_of):
    """Adding c mm to frame 3's real range moves its measured level by c, within 3 standard
    errors; the error is under a millimetre even on 48 × 36 pixels of the noisy camera."""
    frames = sweep({}, camera=NOISY, seed=5)
    problem = problem_of(frames, NOISY)
    before, se = problem.frame_level(3, None)
    problem.real_mm[3] = problem.real_mm[3] + 2.5
    after, se_after = problem.frame_level(3, None)
    assert 0.05 < se < 1.5 and se_after == pytest.approx(se, rel=0.05)
    assert abs((after - before) - 2.5) < 3 * se


def test_levels_statistic():
    """χ² of the held-out levels in their errors; explained = gain >= MIN_CHI2_GAIN and at
    most MAX_CHI2_LEFT of it left; fewer than two frames explain nothing."""
    stepping = FrameLevels((1, 3, 5), (1.5, -0.2, -1.4), (0.1, -0.1, 0.05), (0.2, 0.2, 0.2))
    assert stepping.chi2_before == pytest.approx((1.5**2 + 0.2**2 + 1.4**2) / 0.04)
    assert stepping.explained
    still = FrameLevels((1, 3, 5), (0.2, -0.1, 0.1), (0.0, 0.0, 0.0), (0.2, 0.2, 0.2))
    assert still.chi2_before - still.chi2_after < MIN_CHI2_GAIN and not still.explained
    half = FrameLevels((1, 3, 5), (1.5, -0.2, -1.4), (0.9, -0.1, -0.7), (0.2, 0.2, 0.2))
    assert half.chi2_after > MAX_CHI2_LEFT * half.chi2_before and not half.explained
    assert not FrameLevels((1,), (3.0,), (0.0,), (0.1,)).explained


def test_a_fitted_drift_explains_the_levels_a_control_does_not(sweep, problem_of):
    """The drift fitted on the even frames predicts the odd frames' levels; on the same
    camera without a drift, the best drift fit explains nothing of them."""
    drifting = problem_of(sweep({"temperature_drift": DRIFT}, camera=NOISY, seed=5), NOISY)
    fit = fit_effect(drifting, "temperature_drift")
    levels = frame_levels(drifting, fit.config)
    assert levels is not None and levels.explained, levels
    # the odd frames' levels step by about the drift: 1 mm or more from frame 1 to 5
    assert abs(levels.before_mm[0] - levels.before_mm[-1]) > 1.0
    still = problem_of(sweep({}, camera=NOISY, seed=5), NOISY)
    fit = fit_effect(still, "temperature_drift")
    still_levels = frame_levels(still, fit.config)
    assert still_levels is not None and not still_levels.explained, still_levels
    # only an effect of one offset per frame is judged so
    assert FRAME_LEVEL_EFFECTS == ("temperature_drift",)


def test_small_drift_on_a_noisy_camera_is_named(sweep):
    """In the monitor workflow on a camera 3× noisier than nominal with 5 mm of jitter, a
    −2.8 mm drift over the recording gains less per pixel than even a first round asks, and
    is named on the frames' levels; without it nothing is named."""
    camera = NOISY.with_effect("noise_model", jitter_mm=5.0)
    drift = {"max_mm": -6.0, "tau_frames": 8.0}
    frames = sweep({"temperature_drift": drift}, camera=camera, seed=5, intrinsics=MEDIUM)
    result = analyse(frames, camera, max_effects=1)
    fit = next(r for r in result.rounds[0] if r.effect == "temperature_drift")
    assert result.selected == ["temperature_drift"], [
        (r.effect, round(r.score, 1)) for r in result.rounds[0]]
    assert fit.score < MIN_SCORE  # not significant per pixel: named on the levels
    levels = result.frame_levels["1:temperature_drift"]
    assert levels["explained"] and levels["chi2_after"] < 0.1 * levels["chi2_before"]
    fitted = result.parameters["temperature_drift"]
    at5 = fitted["max_mm"] * (1 - math.exp(-5 / fitted["tau_frames"]))
    assert abs(at5 - drift["max_mm"] * (1 - math.exp(-5 / drift["tau_frames"]))) < 1.0
    ranked = {row["effect"]: row for row in result.ranking()}
    assert ranked["temperature_drift"]["frame_levels"]["explained"]
    control = analyse(sweep({}, camera=camera, seed=5, intrinsics=MEDIUM), camera,
                      max_effects=1)
    assert control.selected == [] and "1:temperature_drift" in control.frame_levels
    assert not any(v["explained"] for v in control.frame_levels.values())
