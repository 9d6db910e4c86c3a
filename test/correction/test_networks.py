"""Networks F and G: architecture, batched heads == four separate nets, function == module."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from tof_mpd_ros.correction.networks import (
    BoundaryNets,
    RangeRecoveryNet,
    boundary_scores,
    recover_range,
)
from tof_mpd_ros.errors import InputError


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def test_paper_architecture_sizes() -> None:
    f = RangeRecoveryNet(generator=_gen(0))
    g = BoundaryNets(generator=_gen(0))
    widths = [(layer.in_features, layer.out_features) for layer in f.layers]
    assert widths == [(280, 40), (40, 10), (10, 10), (10, 1)]
    assert sum(p.numel() for p in f.parameters()) == 280 * 40 + 40 + 40 * 10 + 10 + 110 + 11
    assert sum(p.numel() for p in g.parameters()) == 4 * (240 * 40 + 40 + 40 * 20 + 20 + 42)


def test_range_net_outputs_millimetres_and_recover_adds_range() -> None:
    f = RangeRecoveryNet(generator=_gen(1))
    x = torch.rand(64, 280, generator=_gen(2)) - 0.5
    out = f(x)
    assert out.shape == (64,)
    torch.testing.assert_close(out, 15.0 * f.normalised(x))
    r = torch.full((64,), 300.0)
    torch.testing.assert_close(recover_range(r, x, f), r + out)
    with pytest.raises(InputError, match="must be \\(N,\\) with N = 64"):
        recover_range(r[:3], x, f)


def test_boundary_heads_equal_four_separate_nets() -> None:
    g = BoundaryNets(generator=_gen(3))
    x = torch.rand(50, 280, generator=_gen(4)) - 0.5   # extra b columns are ignored
    logits = g(x)
    assert logits.shape == (50, 4, 2)
    for k in range(4):
        head = nn.Sequential(nn.Linear(240, 40), nn.ReLU(), nn.Linear(40, 20), nn.ReLU(),
                             nn.Linear(20, 2))
        with torch.no_grad():
            head[0].weight.copy_(g.first.weight[40 * k:40 * (k + 1)])
            head[0].bias.copy_(g.first.bias[40 * k:40 * (k + 1)])
            head[2].weight.copy_(g.w2[k].T)
            head[2].bias.copy_(g.b2[k, 0])
            head[4].weight.copy_(g.w3[k].T)
            head[4].bias.copy_(g.b3[k, 0])
        torch.testing.assert_close(logits[:, k], head(x[:, :240]))
        torch.testing.assert_close(boundary_scores(x, g)[:, k],
                                   torch.softmax(head(x[:, :240]), dim=1)[:, 1])


def test_seeded_init_is_deterministic_and_dtype_follows_module() -> None:
    a, b, c = (RangeRecoveryNet(generator=_gen(s)) for s in (7, 7, 8))
    assert all(torch.equal(p, q) for p, q in zip(a.parameters(), b.parameters(), strict=True))
    assert not torch.equal(a.layers[0].weight, c.layers[0].weight)
    g = BoundaryNets(generator=_gen(7)).double()
    assert g(torch.zeros(3, 240)).dtype == torch.float64


def test_feature_width_errors() -> None:
    with pytest.raises(InputError, match=r"expected features \(N, >= 280\), got \(5, 240\)"):
        RangeRecoveryNet()(torch.zeros(5, 240))
    with pytest.raises(InputError, match="BoundaryNets"):
        BoundaryNets()(torch.zeros(5))


def _run_patch_nets(nets, r, a, cfg):
    """PatchNets over a whole frame as one band: (correction, best, group), each (H*W,)."""
    from tof_mpd_ros.correction.encoding import encode_frame, padded_planes
    from tof_mpd_ros.correction.networks import FrameBins, HeadOutputs

    feats, _ = encode_frame(r, a, cfg, boundary_only=True)
    planes = padded_planes(r[None], a[None], cfg)
    n = r.size
    frame = FrameBins(planes.bin_range[0], planes.bin_amplitude[0], planes.valid[0].ravel())
    out = HeadOutputs.zeros(n)
    x = feats.t().contiguous()                       # feature-major, as encode_band writes
    nets.heads(nets.first_layer(x), n, 0, frame, True, True, out, nets.scratch(n))
    return out


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_patch_nets_equal_modules(backend: str) -> None:
    """Both backends of the one inference path compute the modules' function."""
    from tof_mpd_ros.correction.encoding import EncodingConfig, encode_frame
    from tof_mpd_ros.correction.networks import PatchNets

    rng = np.random.default_rng(0)
    r = (300 + 40 * (rng.random((30, 35)) > 0.7) + rng.normal(0, 2, (30, 35))).astype(np.float32)
    a = rng.uniform(0.2, 1.0, (30, 35)).astype(np.float32)
    r[4, 5] = np.nan
    cfg = EncodingConfig(amplitude_max=1.0)
    f, g = RangeRecoveryNet(generator=_gen(11)), BoundaryNets(generator=_gen(12))
    feats, valid = encode_frame(r, a, cfg)
    ok = valid.reshape(-1).numpy()
    out = _run_patch_nets(PatchNets(f, g, 11, 20, backend=backend), r, a, cfg)
    with torch.no_grad():
        want_f = f(feats).numpy()
        probs = g.probabilities(feats).numpy()
    np.testing.assert_allclose(out.correction[ok], want_f[ok], rtol=0, atol=1e-4)
    np.testing.assert_allclose(out.best[ok], probs.max(1)[ok], rtol=0, atol=1e-5)
    np.testing.assert_array_equal(out.group[ok], probs.argmax(1)[ok])
    assert not out.best[~ok].any() and not out.group[~ok].any()
    with torch.no_grad():     # the best head's logit difference and its lead over the next
        logits = g(feats)
        diffs = np.sort((logits[..., 1] - logits[..., 0]).numpy(), axis=1)
    np.testing.assert_allclose(out.logit[ok], diffs[ok, -1], rtol=0, atol=1e-4)
    np.testing.assert_allclose(out.margin[ok], (diffs[:, -1] - diffs[:, -2])[ok], rtol=0,
                               atol=2e-4)
    assert (out.logit[~ok] == -np.inf).all() and (out.margin[~ok] == np.inf).all()
    out16 = _run_patch_nets(PatchNets(f, g, 11, 20, "bfloat16", backend=backend), r, a, cfg)
    assert np.abs(out16.correction - out.correction)[ok].max() < 0.1          # mm
    assert np.abs(out16.best - out.best)[ok].max() < 0.02
    with pytest.raises(InputError, match="do not fit a 9x9"):
        PatchNets(f, g, 9, 20, backend=backend)
    with pytest.raises(InputError, match="precision"):
        PatchNets(f, g, 11, 20, "float16", backend=backend)
    if backend == "torch":
        with pytest.raises(InputError, match=r"int8.*CPU \(numba backend\) only"):
            PatchNets(f, g, 11, 20, "int8", backend=backend)
        return
    out8 = _run_patch_nets(PatchNets(f, g, 11, 20, "int8", backend=backend), r, a, cfg)
    assert np.abs(out8.correction - out.correction)[ok].max() < 0.01   # mm (measured 0.002)
    assert np.abs(out8.best - out.best)[ok].max() < 0.002             # measured 1.4e-4
    assert not out8.best[~ok].any()


def test_int8_first_layer_is_the_exact_integer_product() -> None:
    """int8: per-row weights rint(w / step_j), step_j = max|w_j| / 127, F's rows followed by
    their residuals at step_j / 254; inputs rint(254 x); summed exactly in int32. The scales
    take the sums back to W x: within the roundings for G's rows, ~127x closer for F's."""
    from tof_mpd_ros.correction.networks import PatchNets

    f, g = RangeRecoveryNet(generator=_gen(11)), BoundaryNets(generator=_gen(12))
    nets = PatchNets(f, g, 11, 20, "int8")
    x = (torch.rand(240, 300, generator=_gen(3)) - 0.5).contiguous()   # feature-major
    x[:, 0] = 0.5                                        # the extremes of the encoding
    x[:, 1] = -0.5
    got = nets.first_layer(x)
    assert got.dtype == torch.int32 and got.shape == (240, 300)      # 200 rows + F's 40
    w = nets.weights.first.astype(np.float64)
    step = np.abs(w).max(1) / 127
    high = np.rint(w / step[:, None])
    low = np.rint((w[:40] - high[:40] * step[:40, None]) / (step[:40, None] / 254))
    assert np.abs(low).max() <= 127
    wq = np.concatenate([high, low]).astype(np.int64)
    xq = np.rint(x.numpy().astype(np.float32) * np.float32(254.0)).astype(np.int64)
    np.testing.assert_array_equal(got.numpy(), wq @ xq)
    np.testing.assert_allclose(nets.scale, np.concatenate([step, step[:40] / 254]) / 254,
                               rtol=1e-6)
    terms = got.numpy() * nets.scale[:, None].astype(np.float64)
    approx = terms[:200].copy()
    approx[:40] += terms[200:]
    exact_x = w @ (xq / 254.0)                           # the same inputs, exact weights
    err = np.abs(approx - exact_x)
    # each G term off by at most step/2 * |x| <= step / 4; F's by step / 1016
    assert (err[40:] <= 240 * step[40:, None] / 4).all()
    assert (err[:40] <= 240 * step[:40, None] / 1016).all()
    assert err[:40].mean() < err[40:].mean() / 50
    exact = w @ x.numpy().astype(np.float64)
    assert np.abs(approx - exact).mean() < 0.01 * np.abs(exact).mean()
    with pytest.raises(InputError, match=r"within \[-0.5, 0.5\]"):
        nets.first_layer(x * 3)


def test_int8_refused_where_the_gemm_does_not_run(monkeypatch) -> None:
    from tof_mpd_ros.correction import networks

    monkeypatch.setattr(networks, "int8_gemm_available", lambda: False)
    f, g = RangeRecoveryNet(generator=_gen(11)), BoundaryNets(generator=_gen(12))
    with pytest.raises(InputError, match=r"torch\._int_mm"):
        networks.PatchNets(f, g, 11, 20, "int8")


def test_numba_backend_is_cpu_only() -> None:
    from tof_mpd_ros.correction.networks import PatchNets

    f, g = RangeRecoveryNet(generator=_gen(11)), BoundaryNets(generator=_gen(12))
    assert PatchNets(f, g, 11, 20).backend == "numba"
    with pytest.raises(InputError, match="backend"):
        PatchNets(f, g, 11, 20, device="meta", backend="numba")
    with pytest.raises(InputError, match="backend"):
        PatchNets(f, g, 11, 20, backend="onnx")


def test_the_one_relayout_feeds_both_backends(monkeypatch) -> None:
    """fuse_weights is the only source of the inference weights, for either backend."""
    from tof_mpd_ros.correction import networks

    f, g = RangeRecoveryNet(generator=_gen(11)), BoundaryNets(generator=_gen(12))
    made = []
    real = networks.fuse_weights

    def recording(*args):
        made.append(real(*args))
        return made[-1]

    monkeypatch.setattr(networks, "fuse_weights", recording)
    for backend in ("numba", "torch"):
        nets = networks.PatchNets(f, g, 11, 20, backend=backend)
        assert nets.weights is made[-1]
        np.testing.assert_array_equal(nets.weight.numpy(), made[-1].first)
    assert len(made) == 2
    w = real(f, g, 11, 20)
    # Head k's second layer is g.w2[k] transposed to (out, in); F's first layer is split into
    # its [x_R x_A] columns (stacked over the heads' first layers) and its one-hot tables.
    np.testing.assert_array_equal(w.g_w2[2], g.w2[2].detach().numpy().T)
    np.testing.assert_array_equal(w.first[:40], f.layers[0].weight.detach().numpy()[:, :240])
    np.testing.assert_array_equal(w.first[40 + 3 * 40:], g.first.weight.detach().numpy()[120:])
    # its one-hot columns become one table of the two lookups' sums: [j, b_R, b_A]
    w_f = f.layers[0].weight.detach().numpy()
    assert w.table_bins.shape == (40, 20, 20)
    np.testing.assert_array_equal(w.table_bins[:, 3, 17], w_f[:, 240 + 3] + w_f[:, 260 + 17])
    np.testing.assert_array_equal(w.table_bins[:, 19, 0], w_f[:, 259] + w_f[:, 260])
