"""Fuzzing the weights readers: :func:`load_weights` (the correction model), and the other
.npz weights files, :meth:`ForestArrays.load` (learned baseline) and ``load_calibration`` (CLI).

Wrong keys, dtypes, shapes and NaN/inf (with the digest re-sealed, as a buggy writer would),
metadata JSON with any value anywhere (huge declared dimensions included), damaged bytes.
Property: :class:`WeightsError` (:class:`CalibrationError` for a calibration) naming the file,
or a usable model identical to the saved one where the damage cannot have touched it.
"""

from __future__ import annotations

import functools
import json
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from fuzz_support import (
    FUZZ,
    array_mutations,
    cut,
    flip,
    flips,
    hang_guard,
    mutate_arrays,
    npy_claiming,
    paths_of,
    peak_allocation,
    positions,
    read_or_typed_error,
    replaced,
    save_arrays,
    with_member,
)
from hypothesis import example, given, settings
from hypothesis import strategies as st

from tof_mpd_ros.calibration import IntrinsicCalibration, load_calibration, save_calibration
from tof_mpd_ros.correction.pipeline import CorrectionModel
from tof_mpd_ros.correction.weights import array_digest, load_weights, save_weights
from tof_mpd_ros.errors import CalibrationError, TofMpdError, WeightsError
from tof_mpd_ros.evaluation.baselines.forest import ForestArrays

H, W = 4, 6


def seed_model() -> CorrectionModel:
    rng = np.random.default_rng(4)
    calibration = IntrinsicCalibration(rng.normal(0, 3, (H, W)), rng.uniform(0.98, 1.02, (H, W)),
                                       rng.normal(0, 1, (H, W)), np.ones((H, W), bool))
    return CorrectionModel.untrained(calibration, seed=4)


@functools.cache
def seed_weights() -> bytes:
    with tempfile.TemporaryDirectory(prefix="fuzz_weights_seed_") as tmp:
        return save_weights(Path(tmp) / "seed.npz", seed_model()).read_bytes()


@functools.cache
def seed_arrays() -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The seed file's arrays (metadata removed) and its metadata."""
    with tempfile.TemporaryDirectory(prefix="fuzz_weights_arrays_") as tmp:
        path = Path(tmp) / "seed.npz"
        path.write_bytes(seed_weights())
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    return arrays, json.loads(str(arrays.pop("metadata")))


def sealed(path: Path, arrays: dict[str, np.ndarray], meta: Any) -> Path:
    """Write arrays and metadata with a digest that matches, as a valid (or buggy) writer would:
    the loader must then find what is wrong by itself."""
    if isinstance(meta, dict):
        meta = {**meta, "array_digest": array_digest(arrays)}
    return save_arrays(path, {**arrays, "metadata": np.array(json.dumps(meta))}, False)


@pytest.fixture(scope="module")
def scratch() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="fuzz_weights_") as tmp:
        yield Path(tmp)


def assert_usable(model: CorrectionModel) -> None:
    """A model that can run: its crop, finite calibration and float32 parameters that fit."""
    assert model.shape == model.calibration.shape
    assert np.isfinite(model.calibration.c0).all()
    for net in (model.range_net, model.boundary_nets):
        assert all(p.dtype == torch.float32 and torch.isfinite(p).all() for p in net.parameters())


def assert_as_saved(model: CorrectionModel) -> None:
    assert_usable(model)
    arrays, _ = seed_arrays()
    for prefix, net in (("range_net/", model.range_net), ("boundary_nets/", model.boundary_nets)):
        for name, tensor in net.state_dict().items():
            assert tensor.numpy().tobytes() == arrays[prefix + name].tobytes(), name


def key_index(key: str) -> int:
    """Position of ``key`` among the seed's array names (mutations pick keys modulo this)."""
    return sorted(seed_arrays()[0]).index(key)


def node_index(path: tuple[str, ...]) -> int:
    """Position of a metadata node among :func:`paths_of` (mutations pick nodes modulo this)."""
    return paths_of(seed_arrays()[1]).index(path)


@settings(FUZZ, max_examples=300)
@given(mutations=array_mutations)
@example(mutations=[("value", key_index("range_net/layers.0.weight"), 0, float("nan"))]).via(
    "regression: a NaN network parameter (digest re-sealed) loaded as a usable model")
def test_wrong_arrays_give_a_usable_model_or_a_typed_error(
        scratch: Path, mutations: list[tuple[Any, ...]]) -> None:
    arrays, meta = seed_arrays()
    path = sealed(scratch / "arrays.npz", mutate_arrays(arrays, mutations), meta)
    model = read_or_typed_error(lambda: load_weights(path), path, WeightsError)
    if isinstance(model, CorrectionModel):
        assert_usable(model)


json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-(2**64), 2**64),
              st.sampled_from((0, 1, -1, 2**20, 2**31, 10**9)), st.floats(), st.text(max_size=8)),
    lambda inner: st.one_of(st.lists(inner, max_size=3),
                            st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=6)


@settings(FUZZ, max_examples=300)
@given(where=positions, value=json_values)
@example(where=node_index(("architecture", "range_net", "hidden")), value=[10**6, 10**6]).via(
    "regression: declared hidden widths of 10^6 made torch allocate 4 TB (RuntimeError)")
@example(where=node_index(("crop",)), value=[4, 6]).via(
    "regression: a crop that is not an object raised AttributeError")
def test_any_metadata_value_anywhere_gives_a_usable_model_or_a_typed_error(
        scratch: Path, where: int, value: Any) -> None:
    arrays, meta = seed_arrays()
    nodes = paths_of(meta)
    path = sealed(scratch / "meta.npz", arrays, replaced(meta, nodes[where % len(nodes)], value))
    model = read_or_typed_error(lambda: load_weights(path), path, WeightsError)
    if isinstance(model, CorrectionModel):
        assert_usable(model)


@settings(FUZZ, max_examples=300)
@given(how=st.sampled_from(("flip", "cut")), changes=flips, at=positions)
def test_damaged_bytes_give_the_saved_model_or_a_typed_error(
        scratch: Path, how: str, changes: list[tuple[int, int]], at: int) -> None:
    blob = seed_weights()
    path = scratch / "damaged.npz"
    path.write_bytes(flip(blob, changes) if how == "flip" else cut(blob, at))
    model = read_or_typed_error(lambda: load_weights(path), path, WeightsError)
    if isinstance(model, CorrectionModel):
        assert_as_saved(model)


def test_declared_networks_of_a_trillion_parameters_are_refused_without_allocating_them(
        scratch: Path) -> None:
    arrays, meta = seed_arrays()
    meta = replaced(meta, ("architecture", "range_net", "hidden"), [10**6, 10**6])
    path = sealed(scratch / "huge.npz", arrays, meta)
    with pytest.raises(WeightsError, match=r"huge\.npz: range_net"):
        load_weights(path)
    assert peak_allocation(lambda: load_weights(path)) < 50 * 2**20


def test_a_header_claiming_a_huge_array_is_refused_without_allocating_it(
        scratch: Path) -> None:
    path = scratch / "lying.npz"
    path.write_bytes(seed_weights())
    with_member(path, "range_net/layers.0.weight.npy", npy_claiming((2**15, 2**13)))
    with pytest.raises(WeightsError, match=r"lying\.npz"):
        load_weights(path)
    assert peak_allocation(lambda: load_weights(path)) < 50 * 2**20


# ------------------------------------------------------------------- the other .npz weights

def seed_forest(path: Path) -> Path:
    n = 3
    forest = ForestArrays(left=np.array([1, -1, -1]), right=np.array([2, -1, -1]),
                          feature=np.zeros(n, np.int64), threshold=np.zeros(n),
                          value=np.arange(n, dtype=np.float64), offsets=np.array([0, n]))
    forest.save(path)
    return path


def seed_calibration(path: Path) -> Path:
    save_calibration(path, seed_model().calibration)
    return path


OTHER_READERS: dict[str, tuple[Callable[[Path], Path], Callable[[Path], object],
                               type[TofMpdError]]] = {
    "forest": (seed_forest, ForestArrays.load, WeightsError),
    "calibration": (seed_calibration, load_calibration, CalibrationError),
}


@pytest.mark.parametrize("reader", sorted(OTHER_READERS))
@settings(FUZZ, max_examples=150)
@given(how=st.sampled_from(("flip", "cut", "arrays")), changes=flips, at=positions,
       mutations=array_mutations)
@example(how="cut", changes=[(0, 1)], at=100, mutations=[("drop", 0)]).via(
    "regression: a truncated forest file raised EOFError")
@example(how="arrays", changes=[(0, 1)], at=0, mutations=[("shape", 1, "flat")]).via(
    "regression: a calibration's error did not name the file")
@example(how="arrays", changes=[(0, 1)], at=0, mutations=[("value", 1, 0, 0.0)]).via(
    "regression: a forest whose root is its own child loaded, and predict never returned")
def test_other_npz_weights_load_or_fail_typed(
        scratch: Path, reader: str, how: str, changes: list[tuple[int, int]], at: int,
        mutations: list[tuple[Any, ...]]) -> None:
    write, load, error = OTHER_READERS[reader]
    path = write(scratch / f"{reader}.npz")
    if how == "arrays":
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
        save_arrays(path, mutate_arrays(arrays, mutations), compressed=False)
    else:
        blob = path.read_bytes()
        path.write_bytes(flip(blob, changes) if how == "flip" else cut(blob, at))
    loaded = read_or_typed_error(lambda: load(path), path, error)
    if isinstance(loaded, ForestArrays):  # a forest that loads can be walked to its leaves
        with hang_guard():
            x = np.zeros((2, int(loaded.feature.max(initial=0)) + 1), np.float32)
            assert loaded.predict(x).shape == (2,)
    elif isinstance(loaded, IntrinsicCalibration):
        assert loaded.c1.shape == loaded.c2.shape == loaded.fitted.shape == loaded.shape


def test_metadata_nested_beyond_the_recursion_limit_is_a_typed_error(scratch: Path) -> None:
    arrays, _ = seed_arrays()
    path = save_arrays(scratch / "deep.npz", {**arrays, "metadata": np.array("[" * 100_000)},
                       compressed=False)
    with pytest.raises(WeightsError, match=r"deep\.npz: metadata is not valid JSON"):
        load_weights(path)
