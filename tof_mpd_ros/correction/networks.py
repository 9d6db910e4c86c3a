"""The paper's two networks: range recovery F and the four boundary detectors G.

* F: ``[x_R x_A b_R b_A]`` (280) -> FC 40 -> ReLU -> FC 10 -> ReLU -> FC 10 -> ReLU -> 1.
  The output unit predicts the *normalised* correction ``t / T`` with ``T = target_clip_mm``
  (15 mm): the training target ``t = R* - R`` is truncated to +-T, so ``t / T`` lies in [-1, 1],
  a well-scaled regression target. :meth:`RangeRecoveryNet.forward` multiplies by T and returns
  millimetres.
* G: four identical nets on ``[x_R x_A]`` (240) -> FC 40 -> ReLU -> FC 20 -> ReLU -> 2 (softmax;
  unit 1 = edge, unit 0 = non-edge), one per edge-orientation group. They are stored stacked so
  the four heads run as one GEMM (first layers concatenated, 240 x 160) and two batched GEMMs.

Device and dtype follow the module (move it with ``.to``); inputs are cast to the module's dtype.

Inference has two fused forms: :class:`FusedPatchNets` (torch, any device, column encoding) and
:class:`FastPatchNets` (CPU fast path of ``pipeline.correct``: one oneDNN GEMM for the first layers
of F and the four G heads over a band of pixel-major encodings, then one compiled kernel for
everything after it, cache-resident, no allocation).
"""

from __future__ import annotations

import itertools
import math

import numba
import numpy as np
import torch
from torch import nn

from ..errors import InputError

RANGE_HIDDEN = (40, 10, 10)
BOUNDARY_HIDDEN = (40, 20)
N_ORIENTATIONS = 4
TARGET_CLIP_MM = 15.0


def _uniform_(t: torch.Tensor, bound: float, generator: torch.Generator | None) -> None:
    with torch.no_grad():
        t.uniform_(-bound, bound, generator=generator)


def _check_features(features: torch.Tensor, min_width: int, who: str) -> None:
    if features.ndim != 2 or features.shape[1] < min_width:
        raise InputError(f"{who}: expected features (N, >= {min_width}), "
                         f"got {tuple(features.shape)}")


class RangeRecoveryNet(nn.Module):
    """F: patch encoding -> range correction in mm.

    Args:
        n_features: input width (2 M + 2 n_bins = 280 for the paper's encoding).
        hidden: hidden layer widths (paper: 40, 10, 10).
        target_clip_mm: T; the output unit is scaled by T (see the module docstring).
        generator: seeds the initialisation (PyTorch's default Linear init, drawn from it).
    """

    def __init__(self, n_features: int = 280, hidden: tuple[int, ...] = RANGE_HIDDEN,
                 target_clip_mm: float = TARGET_CLIP_MM,
                 generator: torch.Generator | None = None) -> None:
        super().__init__()
        if not target_clip_mm > 0:
            raise InputError(f"target_clip_mm must be > 0, got {target_clip_mm}")
        widths = (n_features, *hidden, 1)
        self.layers = nn.ModuleList(nn.Linear(i, o) for i, o in itertools.pairwise(widths))
        self.n_features = n_features
        self.hidden = tuple(hidden)
        self.target_clip_mm = float(target_clip_mm)
        self.reset_parameters(generator)

    def reset_parameters(self, generator: torch.Generator | None = None) -> None:
        """PyTorch's Linear initialisation (U(+-1/sqrt(fan_in))), drawn from ``generator``."""
        for layer in self.layers:
            bound = 1.0 / math.sqrt(layer.in_features)
            _uniform_(layer.weight, bound, generator)
            _uniform_(layer.bias, bound, generator)

    def normalised(self, features: torch.Tensor) -> torch.Tensor:
        """Raw output ``t / T``.

        Args:
            features: (N, n_features) float encodings.

        Returns:
            (N,) normalised correction (dimensionless, ~[-1, 1]).
        """
        _check_features(features, self.n_features, "RangeRecoveryNet")
        x = features[:, :self.n_features].to(self.layers[0].weight.dtype)
        for layer in self.layers[:-1]:
            x = torch.relu(layer(x))
        return self.layers[-1](x)[:, 0]

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """Range correction F(p) in mm, (N,) float."""
        return self.normalised(features) * self.target_clip_mm


class BoundaryNets(nn.Module):
    """G: four edge detectors (one per orientation group) evaluated in one batched call.

    Args:
        n_features: input width (2 M = 240 for the paper's encoding); wider inputs are cut.
        hidden: hidden widths of each head (paper: 40, 20).
        n_heads: orientation groups (paper: 4).
        generator: seeds the initialisation.
    """

    def __init__(self, n_features: int = 240, hidden: tuple[int, int] = BOUNDARY_HIDDEN,
                 n_heads: int = N_ORIENTATIONS,
                 generator: torch.Generator | None = None) -> None:
        super().__init__()
        h1, h2 = hidden
        self.n_features, self.hidden, self.n_heads = n_features, (h1, h2), n_heads
        # Head k's first layer is rows [k*h1, (k+1)*h1) of one Linear: one GEMM for all heads.
        self.first = nn.Linear(n_features, n_heads * h1)
        self.w2 = nn.Parameter(torch.empty(n_heads, h1, h2))
        self.b2 = nn.Parameter(torch.empty(n_heads, 1, h2))
        self.w3 = nn.Parameter(torch.empty(n_heads, h2, 2))
        self.b3 = nn.Parameter(torch.empty(n_heads, 1, 2))
        self.reset_parameters(generator)

    def reset_parameters(self, generator: torch.Generator | None = None) -> None:
        """PyTorch's Linear initialisation per head, drawn from ``generator``."""
        h1, h2 = self.hidden
        for t, fan_in in ((self.first.weight, self.n_features), (self.first.bias, self.n_features),
                          (self.w2, h1), (self.b2, h1), (self.w3, h2), (self.b3, h2)):
            _uniform_(t, 1.0 / math.sqrt(fan_in), generator)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """Logits of the four heads.

        Args:
            features: (N, >= n_features) float encodings; the first n_features are used.

        Returns:
            (N, n_heads, 2) float logits, unit 0 = non-edge, unit 1 = edge.
        """
        _check_features(features, self.n_features, "BoundaryNets")
        x = features[:, :self.n_features].to(self.first.weight.dtype)
        n = x.shape[0]
        h = torch.relu(self.first(x)).view(n, self.n_heads, self.hidden[0]).transpose(0, 1)
        h = torch.relu(torch.baddbmm(self.b2, h, self.w2))   # (heads, N, h2)
        out = torch.baddbmm(self.b3, h, self.w3)              # (heads, N, 2)
        return out.transpose(0, 1)

    def probabilities(self, features: torch.Tensor) -> torch.Tensor:
        """Edge probability of each head, softmax(logits)[..., 1]: (N, n_heads) in [0, 1]."""
        logits = self.forward(features)
        return torch.sigmoid(logits[..., 1] - logits[..., 0])


def recover_range(range_mm: torch.Tensor, features: torch.Tensor,
                  net: RangeRecoveryNet) -> torch.Tensor:
    """R_F = R + F: the range network's estimate of the true range (paper eq. 5).

    Args:
        range_mm: (N,) float calibrated range R in mm of the encoded pixels.
        features: (N, 280) float32 encodings of the same pixels.
        net: the trained F.

    Returns:
        (N,) range in mm, dtype of ``range_mm``.
    """
    if range_mm.shape != features.shape[:1]:
        raise InputError(f"range_mm {tuple(range_mm.shape)} must be (N,) with N = "
                         f"{features.shape[0]} rows of features")
    return range_mm + net(features).to(range_mm.dtype)


def boundary_scores(features: torch.Tensor, nets: BoundaryNets) -> torch.Tensor:
    """Edge probability per orientation group.

    Args:
        features: (N, >= 240) float32 encodings.
        nets: the trained G heads.

    Returns:
        (N, 4) float edge probabilities in [0, 1].
    """
    return nets.probabilities(features)


def _check_fusable(range_net: RangeRecoveryNet, boundary_nets: BoundaryNets, patch_size: int,
                   n_bins: int, precision: str) -> int:
    """Neighbours per patch (``patch_size**2 - 1``); raise InputError unless F and G fit one
    ``patch_size``/``n_bins`` encoding and ``precision`` is known (shared by the fused paths)."""
    if precision not in ("float32", "bfloat16"):
        raise InputError(f"precision must be 'float32' or 'bfloat16', got {precision!r}")
    m = patch_size * patch_size - 1
    if range_net.n_features != 2 * m + 2 * n_bins or boundary_nets.n_features != 2 * m:
        raise InputError(f"networks ({range_net.n_features}, {boundary_nets.n_features} "
                         f"inputs) do not fit a {patch_size}x{patch_size}, {n_bins}-bin "
                         "encoding")
    return m


class FusedPatchNets:
    """Inference-only fusion of F and the four G heads over the column encoding.

    The first layers of F (its x_R / x_A part) and of the four G heads read the same patch, so
    they are stacked into one ``(40 + 4 * 40, P*P)`` weight per input plane: two GEMMs against
    the (P*P, N) column encodings give all 200 first-layer pre-activations. F's one-hot terms
    ``W b_R + W b_A`` become two column lookups; the centre rows of the encoding get zero
    weights. Everything stays channels-first ((features, N), as the encoding arrives), so each
    head's hidden units are a contiguous (40, N) block and the heads run as batched GEMMs with
    no transposes or copies. Numerically the same function as the modules (float32 up to
    summation order).

    ``precision="bfloat16"`` runs the first layers as one bfloat16 GEMM (inputs and weights
    rounded to 8 significant bits, accumulated in float32, output rounded to bfloat16): several
    times faster on CPUs with AVX512-BF16/AMX, at an F error of a few hundredths of a millimetre.

    Args:
        range_net: the trained F.
        boundary_nets: the trained G heads.
        patch_size: P of the encoding.
        n_bins: one-hot width of the encoding.
        precision: ``"float32"`` or ``"bfloat16"``.
    """

    def __init__(self, range_net: RangeRecoveryNet, boundary_nets: BoundaryNets,
                 patch_size: int, n_bins: int, precision: str = "float32") -> None:
        m = _check_fusable(range_net, boundary_nets, patch_size, n_bins, precision)
        dtype = torch.bfloat16 if precision == "bfloat16" else torch.float32
        w_f = range_net.layers[0].weight.detach().float()
        w_g = boundary_nets.first.weight.detach().float()
        c = m // 2

        def widen(w: torch.Tensor) -> torch.Tensor:   # (out, M) -> (out, P*P), zero centre
            return torch.cat([w[:, :c], w.new_zeros(w.shape[0], 1), w[:, c:]], 1)

        self.w_range = torch.cat([widen(w_f[:, :m]), widen(w_g[:, :m])]).to(dtype).contiguous()
        self.w_amp = torch.cat([widen(w_f[:, m:2 * m]), widen(w_g[:, m:2 * m])]
                               ).to(dtype).contiguous()
        self.w_both = torch.cat([self.w_range, self.w_amp], 1).contiguous()
        self.bias = torch.cat([range_net.layers[0].bias, boundary_nets.first.bias]
                              ).detach()[:, None]
        self.table_range = w_f[:, 2 * m:2 * m + n_bins].contiguous()   # (40, n_bins)
        self.table_amp = w_f[:, 2 * m + n_bins:].contiguous()
        g = boundary_nets
        self.g_w2 = g.w2.detach().transpose(1, 2).contiguous()        # (heads, h2, h1)
        self.g_b2 = g.b2.detach().transpose(1, 2).contiguous()        # (heads, h2, 1)
        self.g_w3 = g.w3.detach().transpose(1, 2).contiguous()        # (heads, 2, h2)
        self.g_b3 = g.b3.detach().transpose(1, 2).contiguous()        # (heads, 2, 1)
        self.f_layers = [(layer.weight.detach(), layer.bias.detach()[:, None])
                         for layer in range_net.layers[1:]]
        self.n_f, self.n_heads, self.h1 = w_f.shape[0], g.n_heads, g.hidden[0]
        self.target_clip_mm = range_net.target_clip_mm
        self.dtype = dtype

    def __call__(self, x_range: torch.Tensor, x_amp: torch.Tensor, bin_range: torch.Tensor,
                 bin_amp: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """F correction and G edge probabilities of N pixels.

        Args:
            x_range, x_amp: (P*P, N) float32 column encodings (centre row included).
            bin_range, bin_amp: (N,) int64 one-hot bin indices.

        Returns:
            ``(correction_mm, edge_prob)``: (N,) float32 F(p) in mm and (4, N) float32 edge
            probability of each head.
        """
        with torch.no_grad():
            if self.dtype == torch.float32:
                h = torch.addmm(self.bias, self.w_range, x_range).addmm_(self.w_amp, x_amp)
            else:   # one bfloat16 GEMM over both planes (float32 accumulation inside)
                p2 = x_range.shape[0]
                x = x_range.new_empty((2 * p2, x_range.shape[1]), dtype=self.dtype)
                x[:p2].copy_(x_range)
                x[p2:].copy_(x_amp)
                h = torch.mm(self.w_both, x).float().add_(self.bias)
            h[:self.n_f].add_(self.table_range.index_select(1, bin_range)).add_(
                self.table_amp.index_select(1, bin_amp))
            h.relu_()
            x = h[:self.n_f]                                              # (40, N)
            for weight, bias in self.f_layers[:-1]:
                x = torch.addmm(bias, weight, x).relu_()
            weight, bias = self.f_layers[-1]
            correction = torch.addmm(bias, weight, x)[0] * self.target_clip_mm
            hg = h[self.n_f:].view(self.n_heads, self.h1, -1)             # (heads, 40, N)
            hg = torch.baddbmm(self.g_b2, self.g_w2, hg).relu_()           # (heads, 20, N)
            logits = torch.baddbmm(self.g_b3, self.g_w3, hg)              # (heads, 2, N)
            probs = torch.sigmoid(logits[:, 1] - logits[:, 0])            # (heads, N)
        return correction, probs


# ---------------------------------------------------------------------------------------------
# CPU fast path: oneDNN first-layer GEMM + one compiled kernel for the rest.


def _onednn_linear(weight: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``weight @ x.T`` through oneDNN's JIT GEMM (``mkldnn._linear_pointwise``).

    torch's CPU ``mm`` goes to MKL, which on AMD CPUs runs about half as fast (measured on the
    benchmark's Zen 5: 105-110 vs 225-240 GFLOP/s on one core for these shapes, float32, same
    accuracy). The op is the one torch.compile emits for linear layers on CPU.
    """
    return torch.ops.mkldnn._linear_pointwise(weight, x, None, "none", [], "")


def _mkl_linear(weight: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``weight @ x.T`` with torch.mm (fallback when oneDNN is unavailable)."""
    return torch.mm(weight, x.t())


def _pick_linear(dtype: torch.dtype) -> object:
    """oneDNN's GEMM when it runs here and agrees with ``torch.mm``, else ``torch.mm``."""
    try:
        if not torch.backends.mkldnn.is_available():
            return _mkl_linear
        gen = torch.Generator().manual_seed(0)
        w = torch.rand(24, 40, generator=gen).to(dtype)
        x = torch.rand(33, 40, generator=gen).to(dtype)
        got = _onednn_linear(w, x).float()
        want = _mkl_linear(w.float(), x.float())
        tol = 1e-4 if dtype == torch.float32 else 0.1
        if got.shape == want.shape and bool(torch.allclose(got, want, atol=tol, rtol=0)):
            return _onednn_linear
    except (RuntimeError, AttributeError):   # op missing or unsupported in this build
        pass
    return _mkl_linear


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _dense(w: np.ndarray, b: np.ndarray, n_out: int, n_in: int, src: np.ndarray,
           dst: np.ndarray, m: int, relu: bool) -> None:  # pragma: no cover
    """``dst[j, :m] = act(b[j] + sum_i w[j, i] src[i, :m])``, vectorised over pixels.

    Four output rows at a time share each load of ``src`` (1.5x faster than one row at a
    time; every output is still the same sum in the same order).
    """
    zero = np.float32(0.0)
    j = 0
    while j + 4 <= n_out:
        d0, d1, d2, d3 = dst[j], dst[j + 1], dst[j + 2], dst[j + 3]
        b0, b1, b2, b3 = b[j], b[j + 1], b[j + 2], b[j + 3]
        for px in range(m):
            d0[px] = b0
            d1[px] = b1
            d2[px] = b2
            d3[px] = b3
        for i in range(n_in):
            s = src[i]
            w0, w1, w2, w3 = w[j, i], w[j + 1, i], w[j + 2, i], w[j + 3, i]
            for px in range(m):
                v = s[px]
                d0[px] += w0 * v
                d1[px] += w1 * v
                d2[px] += w2 * v
                d3[px] += w3 * v
        if relu:
            for px in range(m):
                d0[px] = max(d0[px], zero)
                d1[px] = max(d1[px], zero)
                d2[px] = max(d2[px], zero)
                d3[px] = max(d3[px], zero)
        j += 4
    while j < n_out:
        d = dst[j]
        bj = b[j]
        for px in range(m):
            d[px] = bj
        for i in range(n_in):
            s = src[i]
            wi = w[j, i]
            for px in range(m):
                d[px] += wi * s[px]
        if relu:
            for px in range(m):
                d[px] = max(d[px], zero)
        j += 1


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _heads_kernel(h, n, start, bin_range, bin_amplitude, valid, bias, tab_r, tab_a, f_w, f_b,
                  f_dims, t_clip, g_w2, g_b2, g_w3, g_b3, do_f, do_g, corr, best, group, hc,
                  fa, fb, tg, lg):  # pragma: no cover
    """Everything after the first-layer GEMM for pixels ``start .. start + n`` of a frame.

    ``h`` (rows, >= n) holds the first layers' ``W x`` (F's rows first, then each G head's);
    this adds the biases and F's one-hot terms, applies ReLU, runs F's remaining layers and the
    G heads in chunks of ``hc.shape[1]`` pixels, and writes F(p) in mm to ``corr``, the maximum
    edge probability over the heads to ``best`` and its head (first on ties) to ``group``
    (both 0 for invalid pixels, as the zeroed scores of the torch path).
    """
    nf = f_dims[0]
    n_layers = f_dims.shape[0] - 1
    n_heads, h2, h1 = g_w2.shape
    rows = h.shape[0]
    ch = hc.shape[1]
    zero = np.float32(0.0)
    for c0 in range(0, n, ch):
        m = min(ch, n - c0)
        q0 = start + c0
        for j in range(rows):
            src = h[j, c0:c0 + m]
            dst = hc[j]
            bj = bias[j]
            if j < nf:
                tr = tab_r[j]
                ta = tab_a[j]
                for px in range(m):
                    v = src[px] + bj + tr[bin_range[q0 + px]] + ta[bin_amplitude[q0 + px]]
                    dst[px] = max(v, zero)
            else:
                for px in range(m):
                    dst[px] = max(src[px] + bj, zero)
        if do_f:
            src2 = hc[:nf]
            for layer in range(n_layers):
                dst2 = fa if layer % 2 == 0 else fb
                last = layer == n_layers - 1
                _dense(f_w[layer], f_b[layer], f_dims[layer + 1], f_dims[layer], src2, dst2, m,
                       not last)
                src2 = dst2
            out = src2[0]
            for px in range(m):
                corr[q0 + px] = out[px] * t_clip
        if do_g:
            for px in range(m):
                best[q0 + px] = -1.0
                group[q0 + px] = 0
            for k in range(n_heads):
                off = nf + k * h1
                _dense(g_w2[k], g_b2[k], h2, h1, hc[off:off + h1], tg, m, True)
                _dense(g_w3[k], g_b3[k], 2, h2, tg, lg, m, False)
                l0 = lg[0]
                l1 = lg[1]
                for px in range(m):
                    # softmax(l)[1] = sigmoid(l1 - l0), in float64 then rounded (as the
                    # reference does it), so the float32 value is the correctly rounded one.
                    e = math.exp(np.float64(l0[px]) - np.float64(l1[px]))
                    p = np.float32(1.0 / (1.0 + e))
                    if p > best[q0 + px]:
                        best[q0 + px] = p
                        group[q0 + px] = k
            for px in range(m):
                if not valid[q0 + px]:
                    best[q0 + px] = zero
                    group[q0 + px] = 0


class FastPatchNets:
    """F and the four G heads over pixel-major ``[x_R x_A]`` bands (CPU fast path).

    The first layers of F (its x_R / x_A columns) and of the four heads are one
    ``(40 + 4 * 40, 2 M)`` weight: one GEMM per band gives all 200 pre-activations (oneDNN when
    available, see :func:`_onednn_linear`). A compiled kernel then adds the biases and F's
    one-hot terms as table lookups and runs the small layers, vectorised over pixels in chunks
    that stay in L1/L2. The same function as the modules up to float32 summation order
    (F within ~2e-5 mm, probabilities within ~1e-6 of the float64 reference).

    ``precision="bfloat16"`` rounds the first layers' inputs and weights to bfloat16 (float32
    accumulation): measured on the benchmark's Zen 5 (AVX512-BF16), networks 18 instead of
    24 ms of CPU per 180x140 frame, but R_F off by up to 0.1 mm and ~0.5 % of the edge pixels
    flipped (so the final range differs by tens of mm next to them): it misses the "same edges,
    1e-3 mm" agreement with the reference that the float32 default keeps. Opt-in only.

    Args:
        range_net: the trained F.
        boundary_nets: the trained G heads.
        patch_size: P of the encoding.
        n_bins: one-hot width of the encoding.
        precision: ``"float32"`` or ``"bfloat16"``.
        chunk: pixels per chunk of the kernel's small layers.
    """

    def __init__(self, range_net: RangeRecoveryNet, boundary_nets: BoundaryNets,
                 patch_size: int, n_bins: int, precision: str = "float32",
                 chunk: int = 256) -> None:
        m = _check_fusable(range_net, boundary_nets, patch_size, n_bins, precision)

        def np32(t: torch.Tensor) -> np.ndarray:
            return np.ascontiguousarray(t.detach().cpu().float().numpy())

        self.dtype = torch.bfloat16 if precision == "bfloat16" else torch.float32
        w_f = range_net.layers[0].weight.detach().cpu().float()
        g = boundary_nets
        self.weight = torch.cat([w_f[:, :2 * m], g.first.weight.detach().cpu().float()]
                                ).to(self.dtype).contiguous()
        self.bias = np32(torch.cat([range_net.layers[0].bias, g.first.bias]))
        self.table_range = np32(w_f[:, 2 * m:2 * m + n_bins])
        self.table_amp = np32(w_f[:, 2 * m + n_bins:])
        rest = range_net.layers[1:]
        self.f_dims = np.array([w_f.shape[0]] + [layer.out_features for layer in rest],
                               np.int64)
        widest = int(max(self.f_dims[1:].max(), 1))
        self.f_w = np.zeros((len(rest), widest, int(self.f_dims[:-1].max())), np.float32)
        self.f_b = np.zeros((len(rest), widest), np.float32)
        for i, layer in enumerate(rest):
            self.f_w[i, :layer.out_features, :layer.in_features] = np32(layer.weight)
            self.f_b[i, :layer.out_features] = np32(layer.bias)
        self.g_w2 = np32(g.w2.transpose(1, 2))                    # (heads, h2, h1)
        self.g_b2 = np32(g.b2[:, 0])                              # (heads, h2)
        self.g_w3 = np32(g.w3.transpose(1, 2))                    # (heads, 2, h2)
        self.g_b3 = np32(g.b3[:, 0])                              # (heads, 2)
        self.rows = self.weight.shape[0]
        self.n_inputs = 2 * m
        self.chunk = int(chunk)
        self.widest = widest
        self.t_clip = np.float32(range_net.target_clip_mm)
        self.linear = _pick_linear(self.dtype)

    def scratch(self) -> tuple[np.ndarray, ...]:
        """Work arrays of one worker for :meth:`heads` (allocate once, reuse every band)."""
        ch = self.chunk
        return (np.empty((self.rows, ch), np.float32), np.empty((self.widest, ch), np.float32),
                np.empty((self.widest, ch), np.float32),
                np.empty((self.g_w2.shape[1], ch), np.float32), np.empty((2, ch), np.float32))

    def first_layer(self, x: torch.Tensor) -> np.ndarray:
        """First-layer ``W x`` (no bias) of n pixels.

        Args:
            x: (n, 2 M) float32 pixel-major ``[x_R x_A]`` (contiguous rows).

        Returns:
            (rows, n) float32 numpy array (channel-major).
        """
        if self.dtype != torch.float32:
            x = x.to(self.dtype)
        return self.linear(self.weight, x).float().numpy()

    def heads(self, h: np.ndarray, n: int, start: int, bin_range: np.ndarray,
              bin_amplitude: np.ndarray, valid: np.ndarray, do_f: bool, do_g: bool,
              corr: np.ndarray, best: np.ndarray, group: np.ndarray,
              scratch: tuple[np.ndarray, ...]) -> None:
        """Run :func:`_heads_kernel` on pixels ``start .. start + n`` (flat frame indices).

        Args:
            h: :meth:`first_layer` output of those pixels.
            n, start: pixel count and first flat index.
            bin_range, bin_amplitude: (H*W,) int32 bins of the frame.
            valid: (H*W,) bool validity of the frame.
            do_f, do_g: run F / the G heads.
            corr, best, group: (H*W,) outputs (float32, float32, int8), written at the pixels.
            scratch: from :meth:`scratch`.
        """
        _heads_kernel(h, n, start, bin_range, bin_amplitude, valid, self.bias,
                      self.table_range, self.table_amp, self.f_w, self.f_b, self.f_dims,
                      self.t_clip, self.g_w2, self.g_b2, self.g_w3, self.g_b3, do_f, do_g, corr,
                      best, group, *scratch)
