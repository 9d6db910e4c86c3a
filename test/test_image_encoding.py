"""Image payload codec and REP 118 depth units."""

from __future__ import annotations

import numpy as np
import pytest

from tof_mpd_ros.errors import InputError
from tof_mpd_ros.image_encoding import (
    amplitude_to_float,
    array_to_image_data,
    depth_to_mm,
    image_to_array,
    mm_to_depth,
)


@pytest.mark.parametrize("encoding", ["32FC1", "64FC1", "16UC1", "mono8"])
def test_round_trip(encoding: str) -> None:
    rng = np.random.default_rng(0)
    array = (rng.uniform(0, 200, (5, 7))).astype({"32FC1": np.float32, "64FC1": np.float64,
                                                  "16UC1": np.uint16, "mono8": np.uint8}[encoding])
    step, data = array_to_image_data(array, encoding)
    assert step == 7 * array.itemsize and len(data) == 5 * step
    np.testing.assert_array_equal(image_to_array(encoding, 5, 7, step, False, data), array)


def test_big_endian_and_row_padding() -> None:
    array = np.arange(6, dtype=np.uint16).reshape(2, 3) + 1000
    rows = [array[i].astype(">u2").tobytes() + b"\xff\xff" for i in range(2)]  # 2 pad bytes
    decoded = image_to_array("16UC1", 2, 3, 8, True, b"".join(rows))
    np.testing.assert_array_equal(decoded, array)


def test_wrong_sizes_and_encodings_are_clear_errors() -> None:
    with pytest.raises(InputError, match="expected 4x12 bytes"):
        image_to_array("32FC1", 4, 3, 12, False, b"\0" * 40)
    with pytest.raises(InputError, match="unsupported image encoding 'rgb8'"):
        image_to_array("rgb8", 1, 1, 3, False, b"\0\0\0")
    with pytest.raises(InputError, match="not a depth encoding"):
        depth_to_mm(np.zeros((2, 2), np.uint8), "mono8")


def test_rep118_units_and_invalid_pixels() -> None:
    metres = np.array([[0.25, np.nan], [np.inf, 0.0]], np.float32)
    mm = depth_to_mm(metres, "32FC1")
    assert mm[0, 0] == pytest.approx(250.0) and np.isnan(mm[0, 1:]).all() and np.isnan(mm[1]).all()
    assert depth_to_mm(np.array([[0, 431]], np.uint16), "16UC1").tolist()[0][1] == 431.0
    assert np.isnan(depth_to_mm(np.array([[0, 431]], np.uint16), "16UC1")[0, 0])
    back = mm_to_depth(np.array([[250.4, np.nan, 70000.0]]), "16UC1")
    assert back.tolist() == [[250, 0, 0]] and back.dtype == np.uint16
    np.testing.assert_allclose(mm_to_depth(np.array([[250.0]]), "32FC1"), [[0.25]])


def test_float64_metres_round_trip_float32_millimetres_exactly() -> None:
    mm = np.random.default_rng(1).uniform(150, 450, 10000).astype(np.float32).reshape(100, 100)
    np.testing.assert_array_equal(depth_to_mm(mm_to_depth(mm, "64FC1"), "64FC1"), mm)


def test_amplitude_to_float_marks_non_finite() -> None:
    out = amplitude_to_float(np.array([[1.0, np.inf]], np.float64))
    assert out.dtype == np.float32 and out[0, 0] == 1.0 and np.isnan(out[0, 1])
