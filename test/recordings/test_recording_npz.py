"""The NPZ interchange: load/save, import/export round trips and bad files."""

from __future__ import annotations

import numpy as np
import pytest
from rec_helpers import make_frames, rigid

from tof_mpd_ros.errors import InputError, RecordingError
from tof_mpd_ros.recordings import (
    RecordingReader,
    export_npz,
    import_npz,
    load_npz,
    save_npz,
)
from tof_mpd_ros.recordings.npz import SYNTH_PERIOD_NS


def _arrays(n=3, h=10, w=14, seed=0, **drop):
    rng = np.random.default_rng(seed)
    out = {
        "range_mm": rng.uniform(100, 3000, (n, h, w)).astype(np.float32),
        "amplitude": rng.uniform(0, 1000, (n, h, w)).astype(np.float32),
        "reference_mm": rng.uniform(100, 3000, (n, h, w)).astype(np.float32),
        "fx": np.float64(110.25), "fy": np.float64(111.5), "cx": np.float64(6.5),
        "cy": np.float64(4.75), "mod_freq_hz": np.float64(31.5e6),
        "stamp_ns": 1_000_000_000 + np.arange(n, dtype=np.int64) * 40_000_017,
        "pose": np.stack([rigid(rng) for _ in range(n)]),
    }
    out["range_mm"][0, 1, 2] = np.nan
    out["range_mm"][-1, :, 0] = np.nan
    out["amplitude"][-1, 3, 3] = np.nan
    out["reference_mm"][:, 5, :] = np.nan
    for key in drop:
        del out[key]
    return out


@pytest.mark.parametrize("drop", [{}, {"stamp_ns": 1}, {"reference_mm": 1, "pose": 1}])
def test_import_export_reproduces_every_array_bit_exactly(tmp_path, drop):
    arrays = _arrays(**drop)
    np.savez(tmp_path / "in.npz", **arrays)
    assert import_npz(tmp_path / "in.npz", tmp_path / "rec") == 3
    assert export_npz(tmp_path / "rec", tmp_path / "out.npz") == 3
    out = dict(np.load(tmp_path / "out.npz"))
    for key, value in arrays.items():
        assert out[key].dtype == value.dtype and out[key].shape == value.shape, key
        assert out[key].tobytes() == value.tobytes(), key
    assert ("reference_mm" in out) == ("reference_mm" in arrays)
    assert ("pose" in out) == ("pose" in arrays)
    if "stamp_ns" not in arrays:  # synthesised at 30 Hz and written on export
        assert out["stamp_ns"].dtype == np.int64
        assert out["stamp_ns"].tolist() == [0, SYNTH_PERIOD_NS, 2 * SYNTH_PERIOD_NS]


def test_import_uses_64fc1_and_records_radial(tmp_path):
    np.savez(tmp_path / "in.npz", **_arrays())
    import_npz(tmp_path / "in.npz", tmp_path / "rec")
    info = RecordingReader(tmp_path / "rec").info()
    assert info.custom_data["tof_mpd_ros.range_encoding"] == "64FC1"
    assert info.range_convention == "radial"
    assert info.custom_data["tof_mpd_ros.mod_freq_hz"] == repr(31.5e6)


def test_single_frame_without_n_axis(tmp_path):
    a = _arrays(n=1)
    single = {k: (v[0] if k in ("range_mm", "amplitude", "reference_mm", "pose") else v)
              for k, v in a.items()}
    single["stamp_ns"] = np.int64(77)
    np.savez(tmp_path / "one.npz", **single)
    (frame,) = load_npz(tmp_path / "one.npz")
    assert frame.stamp_ns == 77 and frame.range_mm.shape == (10, 14)
    assert frame.pose.tobytes() == single["pose"].tobytes()
    assert frame.intrinsics.fx == 110.25 and frame.intrinsics.width == 14


def test_save_load_round_trip_and_refuses_overwrite(tmp_path):
    frames = make_frames(3)
    frames[1].reference_mm = None  # a frame without reference is written as all-NaN
    assert save_npz(tmp_path / "f.npz", frames) == 3
    back = load_npz(tmp_path / "f.npz")
    assert np.isnan(back[1].reference_mm).all()
    assert back[2].reference_mm.tobytes() == frames[2].reference_mm.tobytes()
    assert [f.stamp_ns for f in back] == [f.stamp_ns for f in frames]
    with pytest.raises(RecordingError, match="refusing to overwrite"):
        save_npz(tmp_path / "f.npz", frames)
    other = make_frames(1, intrinsics=frames[0].intrinsics.scaled(2))
    with pytest.raises(InputError, match=r"one \.npz holds one camera"):
        save_npz(tmp_path / "g.npz", frames + other)


def _bad(tmp_path, name, **arrays):
    path = tmp_path / name
    np.savez(path, **arrays)
    return path


@pytest.mark.parametrize(("change", "message"), [
    ({"drop": "fx"}, r"missing key\(s\) fx"),
    ({"drop": "amplitude"}, r"missing key\(s\) amplitude"),
    ({"amplitude": np.zeros((3, 10, 13), np.float32)}, "amplitude has shape"),
    ({"range_mm": np.zeros((10,), np.float32)}, r"range_mm has shape \(10,\)"),
    ({"range_mm": np.array(["a"] * 6).reshape(1, 2, 3)}, "range_mm has dtype <U1"),
    ({"stamp_ns": np.arange(3, dtype=np.float64)}, "stamp_ns has dtype float64"),
    ({"stamp_ns": np.zeros(3, np.int64)}, "duplicate stamps"),
    ({"stamp_ns": np.arange(4, dtype=np.int64)}, r"stamp_ns has shape \(4,\)"),
    ({"pose": np.zeros((3, 3, 3))}, r"pose has shape \(3, 3, 3\)"),
    ({"fx": np.array([1.0, 2.0])}, "fx must be a real scalar"),
    ({"fy": np.float64(np.nan)}, "fy is nan"),
    ({"fx": np.float64(-3.0)}, "focal lengths and size must be > 0"),
    ({"mod_freq_hz": np.float64(0.0)}, "mod_freq_hz must be > 0"),
])
def test_bad_npz_files_name_the_file_and_the_problem(tmp_path, change, message):
    arrays = _arrays()
    if "drop" in change:
        del arrays[change["drop"]]
    else:
        arrays.update(change)
    path = _bad(tmp_path, "bad.npz", **arrays)
    with pytest.raises(RecordingError, match=rf"bad\.npz: .*{message}"):
        load_npz(path)


def test_not_a_zip_object_arrays_and_missing_file(tmp_path):
    (tmp_path / "text.npz").write_text("range_mm,amplitude\n1,2\n")
    with pytest.raises(RecordingError, match=r"text\.npz: is not an \.npz \(zip\) file"):
        load_npz(tmp_path / "text.npz")
    arrays = _arrays()
    arrays["pose"] = np.array([{"evil": 1}], dtype=object)
    np.savez(tmp_path / "obj.npz", **arrays)
    with pytest.raises(RecordingError, match=r"obj\.npz: holds object arrays.*pickle"):
        load_npz(tmp_path / "obj.npz")
    np.save(tmp_path / "plain.npy", np.zeros(3))
    with pytest.raises(RecordingError, match=r"plain\.npy: is a single \.npy array"):
        load_npz(tmp_path / "plain.npy")
    with pytest.raises(RecordingError, match=r"none\.npz: no such file"):
        load_npz(tmp_path / "none.npz")


def test_truncated_npz(tmp_path):
    np.savez(tmp_path / "ok.npz", **_arrays())
    data = (tmp_path / "ok.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(RecordingError, match=r"cut\.npz: is not a readable \.npz"):
        load_npz(tmp_path / "cut.npz")


def test_float64_images_are_converted(tmp_path):
    arrays = _arrays()
    arrays["amplitude"] = arrays["amplitude"].astype(np.float64)
    np.savez(tmp_path / "f64.npz", **arrays)
    frames = load_npz(tmp_path / "f64.npz")
    assert frames[0].amplitude.dtype == np.float32
    np.testing.assert_array_equal(frames[2].amplitude, arrays["amplitude"][2].astype(np.float32))
