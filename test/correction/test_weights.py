"""Weights file: round trip, and every way a file can be wrong -> WeightsError."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from weights_files import rewrite_weights

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.correction.encoding import EncodingConfig, encode_frame
from tof_mpd_ros.correction.pipeline import CorrectionModel
from tof_mpd_ros.correction.weights import load_weights, save_weights
from tof_mpd_ros.errors import WeightsError

H, W = 14, 18


def _model(seed: int = 0) -> CorrectionModel:
    rng = np.random.default_rng(seed)
    calib = IntrinsicCalibration(rng.normal(0, 3, (H, W)), rng.uniform(0.98, 1.02, (H, W)),
                                 rng.normal(0, 1, (H, W)), np.ones((H, W), bool))
    model = CorrectionModel.untrained(calib, EncodingConfig(amplitude_max=3.0), seed=seed)
    model.metadata["note"] = "unit test"
    return model


@pytest.fixture
def saved(tmp_path: Path) -> tuple[Path, CorrectionModel]:
    model = _model()
    return save_weights(tmp_path / "model.npz", model, training_data_digest="abc123"), model


def test_round_trip_reproduces_outputs_and_metadata(saved) -> None:
    path, model = saved
    back = load_weights(path, expected_shape=(H, W))
    rng = np.random.default_rng(1)
    r = rng.uniform(200, 400, (H, W)).astype(np.float32)
    a = rng.uniform(0.1, 2, (H, W)).astype(np.float32)
    np.testing.assert_array_equal(back.calibration.apply(r, a), model.calibration.apply(r, a))
    feats, _ = encode_frame(model.calibration.apply(r, a), a, back.encoding)
    with torch.no_grad():
        torch.testing.assert_close(back.range_net(feats), model.range_net(feats), rtol=0, atol=0)
        torch.testing.assert_close(back.boundary_nets(feats), model.boundary_nets(feats),
                                   rtol=0, atol=0)
    assert back.encoding == model.encoding and back.geodesic == model.geodesic
    info = back.metadata["file"]
    assert info["training_data_digest"] == "abc123"
    assert info["crop"] == {"width": W, "height": H}
    assert info["architecture"]["range_net"]["hidden"] == [40, 10, 10]
    assert info["package_version"] and info["code_revision"]
    assert back.metadata["note"] == "unit test"


def test_refuses_overwrite(saved) -> None:
    path, model = saved
    with pytest.raises(WeightsError, match="exists; pass overwrite=True"):
        save_weights(path, model)
    save_weights(path, model, overwrite=True)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(WeightsError, match="weights file not found"):
        load_weights(tmp_path / "nope.npz")


def test_garbage_and_truncated_files(saved, tmp_path: Path) -> None:
    path, _ = saved
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"definitely not a zip file")
    with pytest.raises(WeightsError, match="not a readable weights file"):
        load_weights(junk)
    data = path.read_bytes()
    for cut in (len(data) // 2, len(data) - 30):
        short = tmp_path / f"short{cut}.npz"
        short.write_bytes(data[:cut])
        with pytest.raises(WeightsError, match="corrupt"):
            load_weights(short)


def test_bit_flip_in_an_array_is_detected(saved, tmp_path: Path) -> None:
    path, _ = saved
    data = bytearray(path.read_bytes())
    start = data.find(b"range_net/layers.0.weight.npy")
    assert start > 0
    data[start + 400] ^= 0x10          # inside the uncompressed array payload
    bad = tmp_path / "flip.npz"
    bad.write_bytes(bytes(data))
    with pytest.raises(WeightsError, match="corrupt"):
        load_weights(bad)


def test_edited_array_fails_digest(saved, tmp_path: Path) -> None:
    path, _ = saved
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["calibration/c0"] = arrays["calibration/c0"] + 1
    bad = tmp_path / "edited.npz"
    with open(bad, "wb") as fh:
        np.savez(fh, **arrays)
    with pytest.raises(WeightsError, match="do not match the stored digest"):
        load_weights(bad)


def test_wrong_architecture(saved, tmp_path: Path) -> None:
    path, _ = saved

    def shrink_first_layer(arrays, meta):
        arrays["range_net/layers.0.weight"] = np.zeros((30, 280), np.float32)

    with pytest.raises(WeightsError, match="range_net parameters do not match its declared "
                                           "architecture"):
        load_weights(rewrite_weights(path, tmp_path / "arch.npz", shrink_first_layer))

    def other_patch_size(arrays, meta):
        meta["encoding"]["patch_size"] = 9

    with pytest.raises(WeightsError, match="networks do not fit the encoding"):
        load_weights(rewrite_weights(path, tmp_path / "enc.npz", other_patch_size))


def test_other_crop_format_and_version(saved, tmp_path: Path) -> None:
    path, _ = saved
    with pytest.raises(WeightsError, match=f"for a {W}x{H} .* crop, expected 180x140"):
        load_weights(path, expected_shape=(140, 180))

    def lie_about_crop(arrays, meta):
        meta["crop"] = {"width": 180, "height": 140}

    with pytest.raises(WeightsError, match="disagrees with the calibration"):
        load_weights(rewrite_weights(path, tmp_path / "crop.npz", lie_about_crop))

    def future(arrays, meta):
        meta["format_version"] = 99

    with pytest.raises(WeightsError, match="format version 99 is not supported"):
        load_weights(rewrite_weights(path, tmp_path / "v99.npz", future))

    def other_format(arrays, meta):
        meta["format"] = "something.else"

    with pytest.raises(WeightsError, match=r"found 'something\.else'"):
        load_weights(rewrite_weights(path, tmp_path / "fmt.npz", other_format))


def test_pickled_payload_is_refused(tmp_path: Path) -> None:
    evil = tmp_path / "evil.npz"
    with open(evil, "wb") as fh:
        np.savez(fh, metadata=np.array([{"x": 1}], dtype=object))
    with pytest.raises(WeightsError, match=r"evil\.npz: holds object arrays .*pickle \(refused\)"):
        load_weights(evil)
