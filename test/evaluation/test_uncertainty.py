"""Calibration of a predicted sigma: coverage, reliability curve, flags — on draws whose truth
is known."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tof_mpd_ros.errors import InputError
from tof_mpd_ros.evaluation.uncertainty import (
    coverage,
    flag_precision_recall,
    gaussian_coverage,
    plot_reliability,
    reliability_curve,
)


def _draws(n: int = 200_000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Errors drawn with a per-pixel sigma of 0.5-8 mm: a calibrated prediction."""
    rng = np.random.default_rng(seed)
    sigma = np.exp(rng.uniform(np.log(0.5), np.log(8.0), n))
    return rng.normal(0.0, sigma), sigma


def test_a_calibrated_sigma_covers_as_the_gaussian_and_a_wrong_one_does_not() -> None:
    err, sigma = _draws()
    got = coverage(err, sigma)
    for k in ("1", "2", "3"):
        assert got[k] == pytest.approx(gaussian_coverage(float(k)), abs=0.005)
    assert gaussian_coverage(2.0) == pytest.approx(0.9545, abs=1e-4)
    over = coverage(err, sigma / 2)            # over-confident: sigma half the truth
    assert over["2"] == pytest.approx(gaussian_coverage(1.0), abs=0.005)


def test_reliability_curve_lies_on_the_diagonal_only_when_calibrated() -> None:
    err, sigma = _draws()
    good = reliability_curve(err, sigma, n_bins=8)
    assert good.count.sum() == err.size and len(good.count) == 8
    np.testing.assert_allclose(good.error_rms_mm / good.sigma_rms_mm, 1.0, atol=0.03)
    assert np.all(np.diff(good.sigma_rms_mm) > 0)
    shuffled = np.random.default_rng(1).permutation(sigma)    # sigma says nothing
    flat = reliability_curve(err, shuffled, n_bins=8)
    assert flat.error_rms_mm.max() / flat.error_rms_mm.min() < 1.1     # error the same ...
    ratio = flat.error_rms_mm / flat.sigma_rms_mm                       # ... sigma is not
    assert ratio.max() / ratio.min() > 5


def test_flags_precision_and_recall() -> None:
    err = np.array([0.0, 1.0, 20.0, -30.0, 2.0, 50.0, np.nan])
    sigma = np.array([1.0, 12.0, 15.0, 11.0, 2.0, 3.0, 20.0])
    got = flag_precision_recall(err, sigma, max_sigma_mm=10.0)
    # flagged: 1, 2, 3 (the NaN pixel is left out); wrong: 2, 3, 5
    assert got["precision"] == pytest.approx(2 / 3)
    assert got["recall"] == pytest.approx(2 / 3)
    assert got["flagged_fraction"] == pytest.approx(3 / 6)
    none = flag_precision_recall(err[:2], sigma[:2], max_sigma_mm=100.0)
    assert np.isnan(none["precision"]) and np.isnan(none["recall"])


def test_mismatched_sizes_are_refused_and_the_plot_is_written(tmp_path: Path) -> None:
    with pytest.raises(InputError):
        coverage(np.zeros(3), np.ones(4))
    err, sigma = _draws(5000)
    out = plot_reliability(reliability_curve(err, sigma), coverage(err, sigma),
                           tmp_path / "sub" / "rel.png", title="test")
    assert out.stat().st_size > 5000 and out.read_bytes()[:4] == b"\x89PNG"
