"""The private APIs of other libraries the package relies on, one test each.

Each is pinned in setup.py to the version tested (mcap-ros2-support==0.6.0, torch==2.13.0). An
upgrade that removes or changes one fails here, with what uses it and what to do, instead of
somewhere deep in a recording or a silent slowdown.
"""

from __future__ import annotations

import importlib.metadata

import numpy as np
import pytest
import torch
from mcap.records import Schema

from tof_mpd_ros.recordings import msgdefs


def _loudly(api: str, package: str, used_by: str) -> str:
    version = importlib.metadata.version(package)
    return (f"{api} is gone or changed in {package} {version}: {used_by}. Pin {package} back to "
            "the version in setup.py, or port that code to the new API.")


def test_mcap_ros2_dynamic_serialises_cdr() -> None:
    """recordings/writer.py encodes every message with ``mcap_ros2._dynamic.serialize_dynamic``
    (the encoder factory mcap_ros2's own Writer uses) because it drives the plain mcap Writer
    itself (rosbag2 QoS metadata, one chunk per frame)."""
    why = _loudly("mcap_ros2._dynamic.serialize_dynamic", "mcap-ros2-support",
                  "tof_mpd_ros.recordings.writer encodes every recorded message with it")
    try:
        from mcap_ros2._dynamic import EncoderFunction, serialize_dynamic
        from mcap_ros2.decoder import DecoderFactory
    except ImportError as err:
        pytest.fail(f"{why} ({err})")
    assert EncoderFunction is not None, why
    text = msgdefs.schema_text(msgdefs.POSE_STAMPED)
    message = {"header": {"stamp": {"sec": 3, "nanosec": 5}, "frame_id": "base"},
               "pose": {"position": {"x": 1.0, "y": 2.0, "z": 3.0},
                        "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}
    try:
        data = serialize_dynamic(msgdefs.POSE_STAMPED, text)[msgdefs.POSE_STAMPED](message)
    except Exception as err:  # any failure means the private API changed
        pytest.fail(f"{why} ({type(err).__name__}: {err})")

    schema = Schema(id=1, name=msgdefs.POSE_STAMPED, encoding="ros2msg", data=text.encode())
    decoded = DecoderFactory().decoder_for("cdr", schema)(data)
    assert decoded.header.frame_id == "base" and decoded.pose.position.z == 3.0, why


@pytest.mark.skipif(not torch.backends.mkldnn.is_available(),
                    reason="no oneDNN in this torch build (the fast path uses torch.mm here)")
def test_onednn_linear_pointwise_is_the_fast_path_gemm() -> None:
    """correction/networks.py runs F and G's first layer through
    ``torch.ops.mkldnn._linear_pointwise`` (about twice as fast as torch.mm on AMD CPUs) and
    falls back to torch.mm, silently, when the op is missing or disagrees."""
    from tof_mpd_ros.correction import networks

    why = _loudly("torch.ops.mkldnn._linear_pointwise", "torch",
                  "tof_mpd_ros.correction.networks would fall back to torch.mm (about half as "
                  "fast on AMD CPUs) without a word")
    rng = np.random.default_rng(0)
    w = torch.from_numpy(rng.standard_normal((24, 40), dtype=np.float32))
    x = torch.from_numpy(rng.standard_normal((33, 40), dtype=np.float32))
    try:
        got = torch.ops.mkldnn._linear_pointwise(w, x, None, "none", [], "")
    except (AttributeError, RuntimeError) as err:
        pytest.fail(f"{why} ({type(err).__name__}: {err})")
    torch.testing.assert_close(got, w @ x.T, atol=1e-4, rtol=0, msg=why)  # as networks calls it
    assert networks._pick_linear(torch.float32) is networks._onednn_linear, why


def test_tensor_version_counts_in_place_changes() -> None:
    """correction/networks.weights_version keys the patch kind's fast-path engine cache and the
    fcn kind's ONNX Runtime sessions on each parameter's ``Tensor._version``, so a model whose
    weights change in place is rebuilt, not reused."""
    why = _loudly("torch.Tensor._version", "torch",
                  "tof_mpd_ros.correction.pipeline and .fcn_onnx would reuse an engine or a "
                  "session built from weights that have since changed in place")
    p = torch.nn.Parameter(torch.zeros(3))
    before = getattr(p, "_version", None)
    assert isinstance(before, int), why
    with torch.no_grad():
        p.add_(1.0)
    assert p._version > before, why
