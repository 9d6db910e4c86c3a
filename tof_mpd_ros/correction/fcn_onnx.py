"""The fcn kind's U-Net run by ONNX Runtime on the CPU: the same graph, another executor.

Why. The U-Net's 19 convolutions are small (8–64 channels), so in torch's eager mode on two
threads each is bound by its call overhead and by waking the sleeping OpenMP thread, not by
arithmetic (docs/performance.md: 20–30 % of the float32 peak on Zen 4). ONNX Runtime plans the
whole graph once, fuses each convolution with its ReLU and runs every operator on one thread
pool of its own: on 2 Zen 4 cores a whole 180×140 correction took 14.1 against torch's 21.6 ms
(docs/performance.md, session 31). On one thread torch's oneDNN convolutions are faster, so
:func:`.fcn.fcn_engine` takes this one on two threads or more. Torch stays the reference and
the trainer's executor; the tests hold this one to it.

Why the graph is written here from the weights, not exported. ``torch.onnx.export``'s
TorchScript exporter is deprecated since torch 2.9 and its successor needs ``onnxscript`` and a
``torch.export`` trace; the architecture is five levels of plain layers stored in the weights
file (:class:`.fcn.FCNArchitecture`), so the graph is built from the module's layers directly —
nothing is traced and no code is loaded.

The executor is chosen by :func:`.fcn.run_fcn` (``engine``); sessions are cached per weights
version and thread count (:func:`session_for`).
"""

from __future__ import annotations

import functools
import os
import threading
import weakref
from typing import Any

import numpy as np
import torch
from torch import nn

from .networks import weights_version

#: ONNX operator set the graph is written in (Resize with ``pytorch_half_pixel``: 11+)
OPSET = 17
#: sessions kept per network (one per weights version and thread count); older ones dropped
MAX_SESSIONS = 4


@functools.cache
def available() -> bool:
    """Whether ONNX Runtime and the ``onnx`` graph builder are installed (asked once: a failed
    import searches the path again on every call)."""
    try:
        import onnx  # noqa: F401
        import onnxruntime  # noqa: F401
    except ImportError:
        return False
    return True


def _conv(nodes: list[Any], inits: list[Any], conv: nn.Conv2d, src: str, name: str,
          relu: bool) -> str:
    """Append ``conv`` (and a ReLU) reading ``src``; returns the output's name."""
    from onnx import helper, numpy_helper

    w = conv.weight.detach().float().cpu().numpy()
    b = conv.bias.detach().float().cpu().numpy()
    inits += [numpy_helper.from_array(w, f"{name}.w"), numpy_helper.from_array(b, f"{name}.b")]
    pad = int(conv.padding[0])
    out = f"{name}.conv"
    nodes.append(helper.make_node(
        "Conv", [src, f"{name}.w", f"{name}.b"], [out], kernel_shape=list(conv.kernel_size),
        strides=list(conv.stride), pads=[pad] * 4))
    if not relu:
        return out
    nodes.append(helper.make_node("Relu", [out], [f"{name}.relu"]))
    return f"{name}.relu"


def _block(nodes: list[Any], inits: list[Any], block: nn.Sequential, src: str,
           name: str) -> str:
    """Two 3×3 convolutions with ReLUs (:func:`.fcn._block`)."""
    convs = [m for m in block if isinstance(m, nn.Conv2d)]
    x = _conv(nodes, inits, convs[0], src, f"{name}.0", relu=True)
    return _conv(nodes, inits, convs[1], x, f"{name}.1", relu=True)


def _upsample_to(nodes: list[Any], src: str, like: str, name: str) -> str:
    """Bilinear resize of ``src`` to the spatial size of ``like`` (torch's ``interpolate``
    with ``align_corners=False``: ONNX's ``pytorch_half_pixel``)."""
    from onnx import helper

    nodes += [
        helper.make_node("Shape", [src], [f"{name}.src_shape"], start=0, end=2),
        helper.make_node("Shape", [like], [f"{name}.like_shape"], start=2, end=4),
        helper.make_node("Concat", [f"{name}.src_shape", f"{name}.like_shape"],
                         [f"{name}.sizes"], axis=0),
        helper.make_node("Resize", [src, "", "", f"{name}.sizes"], [f"{name}.up"],
                         mode="linear", coordinate_transformation_mode="pytorch_half_pixel"),
    ]
    return f"{name}.up"


def unet_graph(net: nn.Module) -> bytes:
    """The serialized ONNX model of ``net.raw`` (:class:`.fcn.ResidualFCN`): input ``x``
    (B, 6, H, W) float32, output ``raw`` (B, 2 + k², H, W) float32, H and W multiples of
    ``net.architecture.multiple``; the weights as float32 initializers."""
    import onnx
    from onnx import TensorProto, helper

    nodes: list[Any] = []
    inits: list[Any] = []
    x, skips = "x", []
    for i, enc in enumerate(net.encoders):
        x = _block(nodes, inits, enc, x, f"enc{i}")
        if i < len(net.downs):
            skips.append(x)
            x = _conv(nodes, inits, net.downs[i], x, f"down{i}", relu=False)
    for i in reversed(range(len(net.decoders))):
        up = _upsample_to(nodes, x, skips[i], f"up{i}")
        nodes.append(helper.make_node("Concat", [skips[i], up], [f"cat{i}"], axis=1))
        x = _block(nodes, inits, net.decoders[i], f"cat{i}", f"dec{i}")
    head = _conv(nodes, inits, net.head, x, "head", relu=False)
    nodes.append(helper.make_node("Identity", [head], ["raw"]))
    n_out = int(net.head.out_channels)
    graph = helper.make_graph(
        nodes, "tof_mpd_fcn_unet",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["B", 6, "H", "W"])],
        [helper.make_tensor_value_info("raw", TensorProto.FLOAT, ["B", n_out, "H", "W"])],
        initializer=inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                              producer_name="tof_mpd_ros")
    onnx.checker.check_model(model)
    return model.SerializeToString()


#: net -> {(weights version, threads, spinning): session}; a net's sessions go with it (a
#: new net may reuse a dead one's id and storage, so neither alone is a key)
_SESSIONS: weakref.WeakKeyDictionary[nn.Module, dict[tuple[Any, ...], Any]] = (
    weakref.WeakKeyDictionary())
_LOCK = threading.Lock()


def _spin() -> str:
    """ONNX Runtime's workers spin only where the user asked OpenMP's to (the package's
    passive waits otherwise: a spinning pool starves the other frame's worker, as OpenMP's
    does, docs/performance.md)."""
    return "1" if os.environ.get("OMP_WAIT_POLICY", "").upper() == "ACTIVE" else "0"


def session_for(net: nn.Module, threads: int) -> Any:
    """An ONNX Runtime session of ``net``'s U-Net on ``threads`` intra-op threads (1: on the
    calling thread only, so the node's parallel frames each keep one core), built on first use
    and cached per weights version and thread count. Safe to call and to run from several
    threads at once."""
    import onnxruntime as ort

    key = (weights_version(net), int(threads), _spin())
    with _LOCK:
        sessions = _SESSIONS.setdefault(net, {})
        session = sessions.get(key)
        if session is not None:
            return session
        options = ort.SessionOptions()
        options.intra_op_num_threads = int(threads)
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        options.add_session_config_entry("session.intra_op.allow_spinning", _spin())
        options.log_severity_level = 3  # warnings about unused initializers are not the user's
        session = ort.InferenceSession(unet_graph(net), options,
                                       providers=["CPUExecutionProvider"])
        while len(sessions) >= MAX_SESSIONS:  # oldest first: a trainer's past weights
            sessions.pop(next(iter(sessions)))
        sessions[key] = session
        return session


def run_unet(net: nn.Module, x: torch.Tensor, threads: int) -> torch.Tensor:
    """``net.raw(x)`` computed by ONNX Runtime: (B, 2 + k², H, W) float32 of ``x``
    (B, 6, H, W) float32 on the CPU."""
    session = session_for(net, threads)
    out = session.run(["raw"], {"x": np.ascontiguousarray(x.numpy(), np.float32)})[0]
    return torch.from_numpy(out)
