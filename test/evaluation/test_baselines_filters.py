"""The unsupervised baselines (JBF, WMF, TV, PD): denoising, edge keeping, NaN handling, and the
maths of TV (Chambolle–Pock energy) and PD (dictionary, candidates, MRF)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from test_baselines_synthetic import make_frame, rmse

from tof_mpd_ros.errors import InputError
from tof_mpd_ros.evaluation.baselines import (
    PD,
    joint_bilateral,
    patch_mrf,
    total_variation,
    weighted_median,
)
from tof_mpd_ros.evaluation.baselines.pd import candidates, generic_dictionary, generic_patches
from tof_mpd_ros.evaluation.baselines.tv import _energy, data_weight, tv_solve

ATOMS = generic_dictionary(5, 512, 0)  # PD's default dictionary (built once, ~4 s)


def pd_small(r: np.ndarray, a: np.ndarray, **kw: float) -> np.ndarray:
    return patch_mrf(r, a, ATOMS, **kw)


FILTERS = {
    "JBF": lambda r, a: joint_bilateral(r, a, sigma_space=2.0, sigma_color=0.1),
    "WMF": lambda r, a: weighted_median(r, a, radius=2, sigma=25.5),
    "TV": lambda r, a: total_variation(r, a, lam=0.2),
    "TV-L1": lambda r, a: total_variation(r, a, lam=1.0, data="l1"),
    "PD": lambda r, a: pd_small(r, a, smoothness=1.0),
}


def step_image(h: int = 40, w: int = 60, noise_mm: float = 3.0, seed: int = 0
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertical step 300 -> 350 mm at column w/2; the far side is darker (inverse square)."""
    truth = np.full((h, w), 300.0, np.float32)
    truth[:, w // 2:] = 350.0
    amp = (0.8 * (300.0 / truth) ** 2).astype(np.float32)
    noisy = truth + np.random.default_rng(seed).normal(0, noise_mm, truth.shape).astype(np.float32)
    return noisy, amp, truth


@pytest.mark.parametrize("name", list(FILTERS))
def test_reduces_flat_region_error(name: str) -> None:
    fr = make_frame(np.random.default_rng(1), noise_mm=3.0)
    out = FILTERS[name](fr.range_mm, fr.amplitude)
    before = rmse(fr.range_mm, fr.reference_mm, fr.flat)
    after = rmse(out, fr.reference_mm, fr.flat)
    assert out.dtype == np.float32 and out.shape == fr.range_mm.shape
    assert after < 0.6 * before, (before, after)


@pytest.mark.parametrize("name", list(FILTERS))
def test_nan_stays_nan_and_never_spreads(name: str) -> None:
    fr = make_frame(np.random.default_rng(2), noise_mm=3.0, holes=12)
    a = fr.amplitude.copy()
    a[5, 5] = np.nan  # an amplitude-only hole invalidates the pixel too
    out = FILTERS[name](fr.range_mm, a)
    invalid = ~np.isfinite(fr.range_mm) | ~np.isfinite(a)
    np.testing.assert_array_equal(np.isnan(out), invalid)
    # Next to holes the estimate is as good as elsewhere: no NaN/fill value leaked in.
    ring = cv2.dilate(invalid.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~invalid
    assert np.nanmax(np.abs(out - fr.reference_mm)[ring & fr.flat]) < 15.0


@pytest.mark.parametrize("name", ["JBF", "WMF"])
def test_guided_filters_keep_step_sharper_than_gaussian(name: str) -> None:
    noisy, amp, truth = step_image()
    out = FILTERS[name](noisy, amp)
    gauss = cv2.GaussianBlur(noisy, (0, 0), 2.0, borderType=cv2.BORDER_REFLECT)
    band = np.zeros(truth.shape, bool)
    band[:, 30 - 3:30 + 3] = True
    assert rmse(out, truth, band) < 0.3 * rmse(gauss, truth, band)


@pytest.mark.parametrize("name", list(FILTERS))
def test_all_invalid_frame_returns_all_nan(name: str) -> None:
    r = np.full((8, 9), np.nan, np.float32)
    out = FILTERS[name](r, np.ones_like(r))
    assert out.shape == (8, 9) and np.isnan(out).all()


def test_bad_input_raises_input_error() -> None:
    with pytest.raises(InputError, match="same shape"):
        joint_bilateral(np.zeros((4, 5)), np.zeros((5, 4)))
    with pytest.raises(InputError, match="dimensions"):
        weighted_median(np.zeros((2, 4, 5)), np.zeros((2, 4, 5)))
    with pytest.raises(InputError, match="sigma"):
        joint_bilateral(np.ones((4, 5)), np.ones((4, 5)), sigma_space=0.0)
    with pytest.raises(InputError, match="data"):
        total_variation(np.ones((4, 5)), np.ones((4, 5)), data="l3")


# --- TV ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("data,lam", [("l2", 0.2), ("l1", 1.0)])
def test_tv_energy_decreases_and_converges(data: str, lam: float) -> None:
    noisy, amp, _ = step_image()
    f = noisy.astype(np.float64) - 325.0
    w = data_weight(amp, np.ones(f.shape, bool), lam, 1.0)
    short: list[float] = []
    tv_solve(f, w, data=data, iterations=300, energies=short)
    long: list[float] = []
    tv_solve(f, w, data=data, iterations=1500, energies=long)
    assert short[-1] < 0.6 * _energy(f, f, w, data)  # well below the energy of u = f
    assert abs(short[-1] - long[-1]) < 2e-3 * long[-1]  # converged
    tail = np.array(short[100:])
    assert np.all(np.diff(tail) < 1e-3 * long[-1])  # monotone up to tiny oscillation


def test_tv_keeps_data_when_lambda_is_huge_and_flattens_when_tiny() -> None:
    noisy, amp, _ = step_image(noise_mm=1.0)
    kept = total_variation(noisy, amp, lam=1e4, data="l1", iterations=50)
    np.testing.assert_allclose(kept, noisy, atol=1e-3)
    flat = total_variation(noisy, amp, lam=1e-4, iterations=2000)
    assert np.ptp(flat) < 0.1 * np.ptp(noisy)


def test_tv_amplitude_weight_trusts_bright_pixels() -> None:
    a = np.array([[0.1, 1.0, 100.0]])
    w = data_weight(a, np.ones(a.shape, bool), 2.0, 1.0)
    np.testing.assert_allclose(w, [[0.2, 2.0, 20.0]])  # (A / median)^1 clipped to [0.1, 10]


# --- PD ---------------------------------------------------------------------------------------

def test_pd_dictionary_is_zero_mean_and_has_the_flat_patch() -> None:
    assert ATOMS.shape == (513, 25)
    np.testing.assert_allclose(ATOMS.mean(axis=1), 0.0, atol=1e-4)
    assert np.any(np.all(ATOMS == 0.0, axis=1))
    p = generic_patches(500, 5, np.random.default_rng(0))
    assert p.shape == (500, 25) and np.ptp(p, axis=1).max() > 100.0  # big steps present


def test_pd_candidates_find_an_exact_atom_with_its_offset() -> None:
    x = (ATOMS[[7, 40]] + np.array([[300.0], [412.5]])).astype(np.float32)
    x[1, 0] = np.nan  # a missing pixel changes neither the best atom nor the offset
    labels, offsets, cost = candidates(x, ATOMS, 3)
    best = np.argmin(cost, axis=1)
    assert labels[0, best[0]] == 7 and labels[1, best[1]] == 40
    np.testing.assert_allclose(offsets[[0, 1], best], [300.0, 412.5], atol=1e-3)
    np.testing.assert_allclose(cost[[0, 1], best], 0.0, atol=1e-3)


def test_pd_keeps_step_sharper_than_box_average_of_its_patch_size() -> None:
    noisy, amp, truth = step_image()
    out = pd_small(noisy, amp, smoothness=1.0)
    box = cv2.blur(noisy, (5, 5), borderType=cv2.BORDER_REFLECT)
    band = np.zeros(truth.shape, bool)
    band[:, 27:33] = True
    assert rmse(out, truth, band) < 0.5 * rmse(box, truth, band)


def test_pd_reference_dictionary_is_learned_from_training_references() -> None:
    rng = np.random.default_rng(6)
    train = [make_frame(rng, noise_mm=3.0) for _ in range(2)]
    method = PD(patch_size=3, n_atoms=32, source="reference")
    with pytest.raises(InputError, match="fit"):
        method.apply(train[0].range_mm, train[0].amplitude)
    method.fit(train)
    assert method.atoms.shape == (33, 9)
    fr = make_frame(rng, noise_mm=3.0)
    out = method.apply(fr.range_mm, fr.amplitude)
    assert rmse(out, fr.reference_mm, fr.flat) < 0.7 * rmse(fr.range_mm, fr.reference_mm, fr.flat)


def test_pd_class_with_its_cache_equals_the_function() -> None:
    rng = np.random.default_rng(7)
    a, b = make_frame(rng, noise_mm=3.0, holes=2), make_frame(rng, noise_mm=3.0)
    method = PD()  # the default dictionary is ATOMS (cached)
    for fr, kw in ((a, {"smoothness": 1.0}), (a, {"smoothness": 0.0}), (b, {"smoothness": 0.0}),
                   (a, {"n_candidates": 4, "smoothness": 2.0})):
        np.testing.assert_array_equal(method.apply(fr.range_mm, fr.amplitude, **kw),
                                      pd_small(fr.range_mm, fr.amplitude, **kw))


def test_pd_pairwise_term_smooths_labels() -> None:
    fr = make_frame(np.random.default_rng(5), noise_mm=3.0)
    e = [rmse(pd_small(fr.range_mm, fr.amplitude, smoothness=s), fr.reference_mm, fr.flat)
         for s in (0.0, 2.0)]
    assert e[1] < e[0]
