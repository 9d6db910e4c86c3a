"""The fcn kind's U-Net under ONNX Runtime: the same function as torch's, never stale weights,
and the executor chosen as documented."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tof_mpd_ros.correction import fcn_onnx
from tof_mpd_ros.correction.fcn import (
    FCNArchitecture,
    ResidualFCN,
    fcn_engine,
    fcn_inputs,
    run_fcn,
)
from tof_mpd_ros.errors import InputError

pytestmark = pytest.mark.skipif(not fcn_onnx.available(),
                                reason="onnxruntime and onnx are not installed")


def _net(seed: int, widths: tuple[int, ...] = (8, 16, 32, 48, 64)) -> ResidualFCN:
    return ResidualFCN(FCNArchitecture(widths=widths),
                       generator=torch.Generator().manual_seed(seed)).eval()


def _frames(shape: tuple[int, ...], seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    r = rng.uniform(300.0, 900.0, shape).astype(np.float32)
    r[..., 10:14, 20:40] = np.nan                   # invalid pixels take the 0 planes
    a = rng.uniform(50.0, 2000.0, shape).astype(np.float32)
    return r, a


@pytest.mark.parametrize("widths", [(8, 16, 32, 48, 64), (4, 6, 8)])
def test_the_graph_computes_the_networks_raw_outputs(widths: tuple[int, ...]) -> None:
    """Every output channel (correction, sigma, kernel logits) of every pixel, on a batch of two
    frames that are not square and need the mirror padding: equal to torch's ``raw`` to float32
    rounding, for the default architecture and a shallower one."""
    net = _net(1, widths)
    r, a = _frames((2, 50, 70))
    x, _ = fcn_inputs(r, a, net.architecture.multiple)
    with torch.inference_mode():
        want = net.raw(x).numpy()
    got = fcn_onnx.run_unet(net, x, threads=2).numpy()
    assert got.shape == want.shape == (2, net.head.out_channels, *x.shape[-2:])
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-5 * float(np.abs(want).max()))


def test_corrections_agree_with_torch_and_follow_weights_changed_in_place() -> None:
    """``run_fcn`` under either executor: the same correction (mm) and sigma on every valid
    pixel. After an in-place change of the weights (a training step) the next ONNX Runtime
    call uses the new weights: its output moves with torch's, not left at the cached graph's."""
    net = _net(2)
    r, a = _frames((1, 64, 80), seed=3)
    want, want_sigma, valid = run_fcn(net, r, a, engine="torch")
    got, got_sigma, got_valid = run_fcn(net, r, a, engine="onnxruntime")
    assert np.array_equal(valid, got_valid) and valid.sum() == 64 * 80 - 4 * 20
    np.testing.assert_allclose(got[valid], want[valid], rtol=0, atol=1e-3)
    np.testing.assert_allclose(got_sigma[valid], want_sigma[valid], rtol=0, atol=1e-4)
    with torch.no_grad():
        net.head.bias[0] += 0.4                      # +4 mm of correction everywhere
    moved, _, _ = run_fcn(net, r, a, engine="onnxruntime")
    again, _, _ = run_fcn(net, r, a, engine="torch")
    np.testing.assert_allclose(moved[valid], again[valid], rtol=0, atol=1e-3)
    assert np.median(moved[valid] - got[valid]) == pytest.approx(4.0, abs=1e-3)


def test_a_new_network_never_gets_an_old_ones_session() -> None:
    """Two networks of the same shape, the first dropped before the second is built (so the
    second may take its id and its storage): each gets its own outputs."""
    r, a = _frames((1, 48, 48), seed=4)
    first = run_fcn(_net(5), r, a, engine="onnxruntime")[0]
    net = _net(6)
    second = run_fcn(net, r, a, engine="onnxruntime")[0]
    want = run_fcn(net, r, a, engine="torch")[0]
    valid = np.isfinite(want)
    np.testing.assert_allclose(second[valid], want[valid], rtol=0, atol=1e-3)
    assert np.abs(second[valid] - first[valid]).max() > 0.1


def test_the_executor_is_chosen_as_documented() -> None:
    """``auto``: ONNX Runtime on the CPU in float32 on two threads or more; torch on one thread
    (where it measured as fast) and for bfloat16 (which ONNX Runtime's CPU convolutions lack).
    Asking for ONNX Runtime where it cannot run, or for an unknown executor, is an InputError
    that says why."""
    saved = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        assert fcn_engine("auto", "cpu", "float32") == "onnxruntime"
        assert fcn_engine("auto", "cpu", "bfloat16") == "torch"
        torch.set_num_threads(1)
        assert fcn_engine("auto", "cpu", "float32") == "torch"
        assert fcn_engine("onnxruntime", "cpu", "float32") == "onnxruntime"
    finally:
        torch.set_num_threads(saved)
    assert fcn_engine("torch", "cpu", "bfloat16") == "torch"
    with pytest.raises(InputError, match="float32 only"):
        fcn_engine("onnxruntime", "cpu", "bfloat16")
    with pytest.raises(InputError, match="engine must be one of"):
        fcn_engine("tensorrt", "cpu", "float32")
