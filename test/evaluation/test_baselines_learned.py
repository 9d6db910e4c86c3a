"""The learned baselines (RF-WF, RFD) and the pickle-free forest export."""

from __future__ import annotations

import numpy as np
import pytest
from test_baselines_synthetic import make_frame, rmse

from tof_mpd_ros.correction.encoding import EncodingConfig
from tof_mpd_ros.errors import InputError, WeightsError
from tof_mpd_ros.evaluation.baselines import RFD, RFWF
from tof_mpd_ros.evaluation.baselines.forest import ForestArrays
from tof_mpd_ros.evaluation.baselines.rfd import encode
from tof_mpd_ros.evaluation.baselines.rfwf import (
    FEATURE_NAMES,
    confidence_filter,
    local_features,
)

ENC = EncodingConfig(range_min_mm=250.0, range_max_mm=500.0, amplitude_min=0.0,
                     amplitude_max=2.0)


@pytest.fixture(scope="module")
def data() -> tuple[list, list]:
    """Six training and two held-out frames with a patch-dependent over-shoot of 12 mm."""
    rng = np.random.default_rng(10)
    frames = [make_frame(rng, noise_mm=1.5, overshoot_mm=12.0) for _ in range(8)]
    return frames[:6], frames[6:]


@pytest.fixture(scope="module")
def rfd(data: tuple[list, list]) -> RFD:
    return RFD(encoding=ENC, n_estimators=8, max_depth=8, samples_per_frame=800).fit(data[0])


@pytest.fixture(scope="module")
def rfwf(data: tuple[list, list]) -> RFWF:
    return RFWF(n_estimators=10, max_depth=10, samples_per_frame=2000).fit(data[0])


def test_rfd_removes_held_out_distortion(rfd: RFD, data: tuple[list, list]) -> None:
    for fr in data[1]:
        out = rfd.apply(fr.range_mm, fr.amplitude)
        near_edges = ~fr.flat
        before = rmse(fr.range_mm, fr.reference_mm, near_edges)
        after = rmse(out, fr.reference_mm, near_edges)
        assert before > 5.0 and after < 0.4 * before, (before, after)


def test_rfd_keeps_nan_and_never_exceeds_the_target_clip(rfd: RFD) -> None:
    fr = make_frame(np.random.default_rng(11), noise_mm=1.5, overshoot_mm=12.0, holes=8)
    out = rfd.apply(fr.range_mm, fr.amplitude)
    np.testing.assert_array_equal(np.isnan(out), np.isnan(fr.range_mm))
    assert np.nanmax(np.abs(out - fr.range_mm)) <= 15.0 + 1e-3


def test_rfd_tree_subsets_match_a_forest_of_that_size(rfd: RFD, data: tuple[list, list]) -> None:
    fr = data[1][0]
    full = rfd.apply(fr.range_mm, fr.amplitude)
    np.testing.assert_allclose(full, rfd.apply(fr.range_mm, fr.amplitude, n_trees=8), atol=1e-4)
    one = rfd.apply(fr.range_mm, fr.amplitude, n_trees=1)
    tree0 = rfd._forest.estimators_[0]
    feats, valid = encode(fr.range_mm, fr.amplitude, ENC)
    expected = fr.range_mm[valid] + tree0.predict(feats[valid.ravel()])
    np.testing.assert_allclose(one[valid], expected, atol=1e-3)
    assert np.abs(one - full)[valid].max() > 0.1


def test_rfwf_confidence_separates_good_from_distorted_pixels(
        rfwf: RFWF, data: tuple[list, list]) -> None:
    fr = data[1][0]
    conf = rfwf.confidence(fr.range_mm, fr.amplitude)
    err = np.abs(fr.range_mm - fr.reference_mm)
    assert conf[err < 2.0].mean() > 0.6 > 0.3 > conf[err > 8.0].mean()


def test_rfwf_reduces_flat_error_but_blurs_steps(rfwf: RFWF, data: tuple[list, list]) -> None:
    for fr in data[1]:
        out = rfwf.apply(fr.range_mm, fr.amplitude, sigma=1.5, power=2.0)
        assert rmse(out, fr.reference_mm, fr.flat) < 0.4 * rmse(fr.range_mm, fr.reference_mm,
                                                                fr.flat)
        # The documented weakness: a confident near surface pulls distorted far-side pixels.
        assert rmse(out, fr.reference_mm, ~fr.flat) > rmse(fr.range_mm, fr.reference_mm,
                                                           ~fr.flat)


def test_rfwf_nan_and_cached_confidence_follow_the_input(rfwf: RFWF) -> None:
    fr = make_frame(np.random.default_rng(12), noise_mm=1.5, holes=8)
    a = rfwf.apply(fr.range_mm, fr.amplitude, sigma=1.0)
    np.testing.assert_array_equal(np.isnan(a), np.isnan(fr.range_mm))
    other = make_frame(np.random.default_rng(13), noise_mm=1.5)
    b = rfwf.apply(other.range_mm, other.amplitude, sigma=1.0, power=2.0)  # not a's confidence
    conf = rfwf.confidence(other.range_mm, other.amplitude)
    expected = confidence_filter(other.range_mm, conf, np.isfinite(other.range_mm), sigma=1.0,
                                 power=2.0)
    np.testing.assert_allclose(b, expected, atol=1e-4)


def test_local_features_shape_and_units() -> None:
    fr = make_frame(np.random.default_rng(14), noise_mm=0.0)
    valid = np.isfinite(fr.range_mm)
    f = local_features(fr.range_mm, fr.amplitude, valid)
    assert f.shape == (*fr.range_mm.shape, len(FEATURE_NAMES)) and f.dtype == np.float32
    np.testing.assert_allclose(f[..., 1], fr.range_mm, atol=1e-3)  # range feature is in mm
    assert f[..., 0].max() <= 1.0  # amplitude scaled by its 99th percentile, clipped


def test_unfitted_or_untrainable_raise_input_error() -> None:
    fr = make_frame(np.random.default_rng(15))
    with pytest.raises(InputError, match="fit"):
        RFD(encoding=ENC).apply(fr.range_mm, fr.amplitude)
    with pytest.raises(InputError, match="fit"):
        RFWF().apply(fr.range_mm, fr.amplitude)
    fr.reference_mm = np.full_like(fr.range_mm, np.nan)
    with pytest.raises(InputError, match="reference"):
        RFWF(n_estimators=2).fit([fr])


def test_forest_arrays_predict_like_sklearn_and_round_trip(rfd: RFD, data: tuple[list, list],
                                                          tmp_path) -> None:
    arrays = rfd.forest_arrays()
    path = tmp_path / "rfd_forest.npz"
    arrays.save(path)
    loaded = ForestArrays.load(path)
    fr = data[1][0]
    feats, valid = encode(fr.range_mm, fr.amplitude, ENC)
    x = feats[valid.ravel()][:2000]
    np.testing.assert_allclose(loaded.predict(x), rfd._forest.predict(x), rtol=0, atol=1e-9)
    (tmp_path / "bad.npz").write_bytes(b"not an npz")
    with pytest.raises(WeightsError):
        ForestArrays.load(tmp_path / "bad.npz")
