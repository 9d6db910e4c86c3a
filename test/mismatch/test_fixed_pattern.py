"""The camera's fixed pattern: an empirical-Bayes estimate of per-pixel offsets from several
frames, which keeps what is white from pixel to pixel and leaves smooth residual alone."""

from __future__ import annotations

import numpy as np
import pytest

from tof_mpd_ros.mismatch.fit import fixed_pattern

SHAPE = (72, 96)


def _frames(rng, pattern_mm: float, noise_mm: float = 1.0, n: int = 3,
            blob_mm: float = 0.0) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
    """``n`` residual frames: a white pattern of std ``pattern_mm`` (the same in every frame),
    white noise, and a smooth blob of ``blob_mm`` (σ 12 px) that moves 15 px per frame, as a
    halo or an interreflection does when the arm moves."""
    truth = rng.normal(0.0, pattern_mm, SHAPE)
    v, u = np.mgrid[0:SHAPE[0], 0:SHAPE[1]]
    res, sig = [], []
    for k in range(n):
        blob = blob_mm * np.exp(-((u - 30 - 15 * k) ** 2 + (v - 36) ** 2) / (2 * 12.0 ** 2))
        res.append(truth + blob + rng.normal(0.0, noise_mm, SHAPE))
        sig.append(np.full(SHAPE, noise_mm))
    return truth, res, sig


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(a.ravel(), b.ravel())[0, 1])


def test_a_pattern_is_found_with_its_size():
    truth, res, sig = _frames(np.random.default_rng(0), pattern_mm=3.0)
    found = fixed_pattern([0, 2, 4], res, sig)
    assert found.rms_mm == pytest.approx(3.0, rel=0.1)
    # shrunk by tau² / (tau² + σ²/3) = 9 / 9.33: the estimate follows the truth closely
    assert _corr(found.full, truth) > 0.95
    assert np.sqrt(np.mean((found.full - truth) ** 2)) < 0.8
    # a frame's own estimate comes from the other two frames: its own noise is not in it
    own_noise = res[0] - truth
    assert abs(_corr(found.of_frame(0) - truth, own_noise)) < 0.05
    assert _corr(found.full - truth, own_noise) > 0.3
    assert found.of_frame(1) is found.full          # a held-out frame gets the full estimate


def test_no_pattern_gives_none():
    _, res, sig = _frames(np.random.default_rng(1), pattern_mm=0.0)
    found = fixed_pattern([0, 2, 4], res, sig)
    assert found.rms_mm < 0.15
    assert np.sqrt(np.mean(found.full ** 2)) < 0.05


def test_noise_the_model_under_states_is_not_read_as_a_pattern():
    """The analysis fits the noise law with the pattern projected out, so the pattern must not
    lean on the model's σ: noise 2.5× what σ says gives no pattern (the frames' noise is
    independent), and a real pattern is still found at its size."""
    _, res, sig = _frames(np.random.default_rng(4), pattern_mm=0.0, noise_mm=2.5)
    told = [s / 2.5 for s in sig]
    assert fixed_pattern([0, 2, 4], res, told).rms_mm < 0.3
    truth, res, sig = _frames(np.random.default_rng(5), pattern_mm=3.0, noise_mm=2.5)
    found = fixed_pattern([0, 2, 4], res, [s / 2.5 for s in sig])
    assert found.rms_mm == pytest.approx(3.0, rel=0.1)
    # shrunk by the noise it really has (v = 6.25 / 3): std τ² / √(τ² + v), and following
    # the truth as that shrinkage allows (correlation τ / √(τ² + v) = 0.90)
    assert np.std(found.full) == pytest.approx(9 / np.sqrt(9 + 6.25 / 3), rel=0.05)
    assert _corr(found.full, truth) == pytest.approx(3 / np.sqrt(9 + 6.25 / 3), abs=0.03)


def test_smooth_residual_is_left_for_the_effects():
    """A 20 mm blob that moves over the image is a scene effect's, not the camera's pattern:
    what the estimate takes of it is a small share of its size (its local mean is removed, and
    the frames see it at different pixels)."""
    truth, res, sig = _frames(np.random.default_rng(2), pattern_mm=2.0, blob_mm=20.0)
    found = fixed_pattern([0, 2, 4], res, sig)
    assert found.rms_mm == pytest.approx(2.0, rel=0.15)
    blob_taken = found.full - truth * (found.rms_mm ** 2 / (found.rms_mm ** 2 + 1 / 3))
    assert np.max(np.abs(blob_taken)) < 0.15 * 20.0


def test_outliers_and_missing_pixels_are_handled():
    truth, res, sig = _frames(np.random.default_rng(3), pattern_mm=3.0)
    res[0][:10, :10] = 400.0          # flying pixels: clipped at a few σ
    res[1][40:, 50:] = np.nan         # unseen in one frame
    found = fixed_pattern([0, 2, 4], res, sig)
    assert np.all(np.isfinite(found.full))
    assert np.max(np.abs(found.full[:10, :10])) < 3.0 * 1.0 + 4 * 3.0
    assert found.rms_mm == pytest.approx(3.0, rel=0.15)
    # away from the flying pixels (and the blur's reach of them) the pattern is still found
    assert _corr(found.full[20:, :50], truth[20:, :50]) > 0.95


def test_a_problem_judges_every_model_with_the_pattern_projected_out(sweep, problem_of):
    """On frames of a camera with a 3 mm pattern of its own (another seed), the model with the
    pattern projected out fits the held-out frames better; a training frame is judged with the
    estimate from the other training frames; without ``free_pattern`` nothing changes."""
    from tof_mpd_ros.sim.tof import ToFConfig

    nominal = ToFConfig.nominal()
    camera = (nominal.with_effect("noise_model", enabled=True, scale=0.33)
              .with_effect("pixel_offset", seed=7, offset_std_mm=3.0, gain_std=0.0))
    plain = problem_of(sweep({}, camera=camera), nominal)
    projected = plain.judged(free_pattern=True)
    assert plain.fixed_pattern(None) is None and plain.pattern(0, None) == 0.0
    found = projected.fixed_pattern(None)
    # the pattern the camera has beyond the config's (2 mm of the nominal seed): √(3² + 2²)
    assert found.rms_mm == pytest.approx(np.sqrt(13.0), rel=0.2)
    train = projected.frames_of("train")
    assert set(found.leave_one_out) == set(train)
    assert not np.allclose(projected.pattern(train[0], None), found.full)
    cost_plain, n = plain.total_cost(None, "test")
    cost_projected, m = projected.total_cost(None, "test")
    assert n == m and (cost_plain - cost_projected) / n > 0.2    # nats per held-out pixel
