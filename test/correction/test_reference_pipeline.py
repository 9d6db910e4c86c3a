"""The straightforward reference pipeline agrees with the production path, stage by stage.

Small frames (30 x 40) so that the per-pixel Python reference stays fast; an untrained model
(fixed seed) and one trained for a few epochs by the real trainer on synthetic box scenes.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from oracles import reference_pipeline as ref

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.correction import geodesic
from tof_mpd_ros.correction.encoding import EncodingConfig, encode_frame
from tof_mpd_ros.correction.pipeline import CorrectionModel, correct
from tof_mpd_ros.errors import InputError
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.training import TrainConfig, train

H, W = 30, 40


def _scene(rng: np.random.Generator, holes: bool = True) -> ToFFrame:
    """A tilted table with a box (and a diagonal-edged wedge), multipath-like bump, holes."""
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    table = rng.uniform(380, 460) + rng.uniform(-0.8, 0.8) * (xx - W / 2)
    top, left = rng.integers(3, 12), rng.integers(3, 18)
    box = np.zeros((H, W), bool)
    box[top:top + rng.integers(8, 15), left:left + rng.integers(8, 18)] = True
    box |= (xx + yy > 55) & (yy > 10)                    # a diagonal silhouette
    reference = np.where(box, table - rng.uniform(60, 140), table)
    bump = np.where(box, 0.0, 12.0 * np.exp(-np.abs(xx - left) / 2.0))
    amplitude = rng.uniform(0.3, 0.9) * (400.0 / reference) ** 2 * 500.0
    measured = reference + bump + rng.normal(0, 0.5, (H, W))
    if holes:
        measured[rng.random((H, W)) < 0.03] = np.nan   # scattered dropouts
        measured[20:24, 3:7] = np.nan                   # a hole
        amplitude[2, 30] = 0.0                          # invalid amplitude
    intr = Intrinsics.from_fov(W, H, 40.0)
    return ToFFrame(measured.astype(np.float32), amplitude.astype(np.float32), intr,
                    reference_mm=reference.astype(np.float32))


def _calibration(seed: int) -> IntrinsicCalibration:
    """A non-trivial per-pixel calibration (offset, gain and amplitude term vary by pixel)."""
    rng = np.random.default_rng(seed)
    return IntrinsicCalibration(rng.normal(2.0, 1.0, (H, W)), rng.normal(1.0, 0.002, (H, W)),
                                rng.normal(0.0, 1e-3, (H, W)), np.ones((H, W), bool))


@pytest.fixture(scope="module")
def frames() -> list[ToFFrame]:
    rng = np.random.default_rng(7)
    return [_scene(rng) for _ in range(3)]


@pytest.fixture(scope="module")
def untrained() -> CorrectionModel:
    return CorrectionModel.untrained(_calibration(1), EncodingConfig(
        range_min_mm=250.0, range_max_mm=500.0, amplitude_min=100.0, amplitude_max=900.0), seed=3)


@pytest.fixture(scope="module")
def trained() -> CorrectionModel:
    rng = np.random.default_rng(11)
    train_frames = [_scene(rng, holes=False) for _ in range(6)]
    cfg = TrainConfig(epochs=4, val_fraction=0.0, max_samples_per_frame=800)
    model, _ = train(train_frames, _calibration(2), cfg, seed=0, progress=False)
    return model


def test_encoding_is_bit_identical(untrained, frames) -> None:
    f = frames[0]
    calibrated = untrained.calibration.apply(f.range_mm, f.amplitude)
    np.testing.assert_array_equal(
        ref.reference_calibration(untrained.calibration, f.range_mm, f.amplitude), calibrated)
    feats, valid = ref.reference_encode(calibrated, f.amplitude, untrained.encoding)
    fast, fast_valid = encode_frame(calibrated, f.amplitude, untrained.encoding)
    np.testing.assert_array_equal(valid, fast_valid[0].numpy())
    np.testing.assert_array_equal(feats, fast.numpy())
    assert (~valid).sum() > 10 and (feats[valid.ravel(), 240:].sum(1) == 2).all()


def test_networks_match_the_modules(trained, frames) -> None:
    f = frames[1]
    calibrated = trained.calibration.apply(f.range_mm, f.amplitude)
    feats, _ = encode_frame(calibrated, f.amplitude, trained.encoding)
    weights = ref.ReferenceWeights.from_model(trained)
    with torch.no_grad():
        f_mm = trained.range_net(feats).numpy()
        probs = trained.boundary_nets.probabilities(feats).numpy()
    np.testing.assert_allclose(ref.reference_range_net(weights, feats.numpy()), f_mm, atol=1e-4)
    np.testing.assert_allclose(ref.reference_boundary_nets(weights, feats.numpy()), probs,
                               atol=1e-6)


@pytest.mark.parametrize("fill_missing", [True, False])
def test_geodesic_reference_equals_the_kernel(fill_missing: bool) -> None:
    rng = np.random.default_rng(5)
    r = (300 + rng.normal(0, 3, (H, W))).astype(np.float32)
    r[:, 20:] += 50.0
    edges = rng.random((H, W)) < 0.06
    edges[:, 19] = True
    edges[3:8, 19] = False                              # a gap to leak through
    edges[np.arange(25), (np.arange(25) + 5) % W] = True  # a diagonal barrier (corner cuts)
    r[rng.random((H, W)) < 0.05] = np.nan
    r[18:26, 2:10] = np.nan
    for max_distance in (None, 5.0):
        fast = geodesic.geodesic_filter(r, edges, fill_missing=fill_missing,
                                        max_distance=max_distance)
        slow = ref.reference_geodesic_filter(r, edges, fill_missing=fill_missing,
                                             max_distance=max_distance)
        np.testing.assert_array_equal(np.isnan(slow), np.isnan(fast))
        np.testing.assert_allclose(slow, fast, atol=1e-4, equal_nan=True)


@pytest.mark.parametrize("which", ["untrained", "trained"])
def test_reference_matches_correct(which: str, frames, request) -> None:
    model = request.getfixturevalue(which)
    n_edges = 0
    for f in frames:
        fast = correct(model, f.range_mm, f.amplitude)
        slow = ref.reference_correct(model, f.range_mm, f.amplitude)
        np.testing.assert_array_equal(slow.valid, fast.valid)
        np.testing.assert_array_equal(slow.calibrated_mm, fast.calibrated_mm)
        np.testing.assert_array_equal(slow.edges, fast.edges)               # same edges
        np.testing.assert_array_equal(np.isnan(slow.range_mm), np.isnan(fast.range_mm))
        np.testing.assert_allclose(slow.range_f_mm, fast.range_f_mm, atol=1e-3, equal_nan=True)
        np.testing.assert_allclose(slow.range_mm, fast.range_mm, atol=1e-3, equal_nan=True)
        np.testing.assert_allclose(slow.confidence, fast.confidence, atol=1e-5)
        n_edges += int(fast.edges.sum())
    if which == "trained":
        assert n_edges > 20          # the edge and geodesic stages were really exercised


def test_component_switches_match(trained, frames) -> None:
    f = frames[2]
    for use_f, use_g in ((False, True), (True, False), (False, False)):
        fast = correct(trained, f.range_mm, f.amplitude, use_range_net=use_f,
                       use_boundary=use_g)
        slow = ref.reference_correct(trained, f.range_mm, f.amplitude, use_range_net=use_f,
                                     use_boundary=use_g)
        np.testing.assert_array_equal(slow.edges, fast.edges)
        np.testing.assert_allclose(slow.range_mm, fast.range_mm, atol=1e-3, equal_nan=True)
        np.testing.assert_allclose(slow.confidence, fast.confidence, atol=1e-5)


def test_reference_takes_one_frame(untrained, frames) -> None:
    f = frames[0]
    with pytest.raises(InputError):
        ref.reference_correct(untrained, f.range_mm[None], f.amplitude[None])
    with pytest.raises(InputError):
        ref.reference_correct(untrained, f.range_mm[:, :-1], f.amplitude[:, :-1])


def test_the_oracle_is_not_shipped() -> None:
    """The oracle lives under test/ only: not a module of the package, imported by none."""
    import importlib.util
    from pathlib import Path

    import tof_mpd_ros

    assert importlib.util.find_spec("tof_mpd_ros.correction.reference_pipeline") is None
    assert Path(ref.__file__).parent.name == "oracles"
    package = Path(tof_mpd_ros.__file__).parent
    users = [p for p in package.rglob("*.py")
             if "import oracles" in (text := p.read_text(encoding="utf-8"))
             or "from oracles" in text]
    assert users == []
