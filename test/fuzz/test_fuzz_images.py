"""Fuzzing the ROS image decoders (live stream and recordings): encodings, steps and sizes that
lie about the payload.

Property: the package's typed error (:class:`FrameRejected` with a known reason for the stream,
:class:`InputError` for recordings), or an (height, width) float32 image — never another
exception, never a hang, never an allocation the payload cannot back.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from fuzz_support import FUZZ, hang_guard, peak_allocation
from hypothesis import example, given, settings
from hypothesis import strategies as st

from tof_mpd_ros.correction.depth_stream import (
    DROP_REASONS,
    FrameRejected,
    decode_amplitude,
    decode_depth,
)
from tof_mpd_ros.errors import InputError
from tof_mpd_ros.recordings.convert import amplitude_of, range_mm_of

ENCODINGS = ("32FC1", "64FC1", "16UC1", "mono16", "mono8", "8UC1", "rgb8", "bgra8", "",
             "32fc1", "16UC1 ", "32FC3")
# uint32 message fields: small, plausible, or large enough to overflow a product
sizes = st.one_of(st.integers(0, 9), st.sampled_from((2**16, 2**31 - 1, 2**32 - 1, 10**6)))
payloads = st.one_of(
    st.binary(max_size=300), st.binary(max_size=64).map(bytearray),
    st.lists(st.floats(width=32), max_size=40).map(lambda v: np.array(v, np.float32)))


def fields(encoding: str, height: int, width: int, step: int, big: bool,
           data: object) -> dict[str, object]:
    return {"encoding": encoding, "height": height, "width": width, "step": step,
            "is_bigendian": big, "data": data}


@settings(FUZZ, max_examples=400)
@given(encoding=st.sampled_from(ENCODINGS), height=sizes, width=sizes, step=sizes,
       big=st.booleans(), data=payloads, depth=st.booleans())
@example(encoding="mono8", height=1, width=4, step=4, big=False,
         data=np.array([1, 2, 3, 4], np.float32), depth=False).via(
    "regression: an ndarray payload of float32 was value-cast to uint8, not read as bytes")
def test_stream_decoders_give_an_image_or_a_frame_rejection(
        encoding: str, height: int, width: int, step: int, big: bool, data: object,
        depth: bool) -> None:
    decode = decode_depth if depth else decode_amplitude
    try:
        with hang_guard():
            image = decode(encoding, height, width, step, big, data)
    except FrameRejected as err:
        assert err.reason in DROP_REASONS and str(err)
        return
    assert image.shape == (height, width) and image.dtype == np.float32
    payload = data.tobytes() if isinstance(data, np.ndarray) else bytes(data)
    assert image.size <= len(payload)  # each pixel was in the payload (>= 1 byte)
    # the same bytes decode the same, whatever buffer type holds them
    again = decode(encoding, height, width, step, big, payload)
    assert again.tobytes() == image.tobytes()


@settings(FUZZ, max_examples=300)
@given(encoding=st.sampled_from(ENCODINGS), height=sizes, width=sizes, step=sizes,
       big=st.booleans(), data=payloads, ranged=st.booleans())
def test_recorded_image_decoders_give_an_image_or_an_input_error(
        encoding: str, height: int, width: int, step: int, big: bool, data: object,
        ranged: bool) -> None:
    message = SimpleNamespace(**fields(encoding, height, width, step, big, data))
    try:
        with hang_guard():
            image = (range_mm_of if ranged else amplitude_of)(message, "fuzzed image")
    except InputError as err:
        assert "fuzzed image" in str(err)
        return
    assert image.shape == (height, width) and image.dtype == np.float32


def test_a_header_claiming_a_trillion_pixels_is_refused_without_allocating_them() -> None:
    args = ("32FC1", 10**6, 10**6, 4 * 10**6, False, b"\0" * 64)
    try:
        decode_depth(*args)
    except FrameRejected as err:
        assert err.reason == "bad_image"
    else:
        raise AssertionError("a 64-byte payload decoded as 10^12 pixels")
    assert peak_allocation(lambda: decode_depth(*args)) < 2**20
