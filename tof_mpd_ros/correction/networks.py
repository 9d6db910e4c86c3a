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
The modules are what training optimises (and what the evaluation's per-component scores call).

Inference (``pipeline.correct``) has one path, :class:`PatchNets`, over one re-layout of the
weights, :class:`FusedWeights`: one GEMM for the first layers of F and the four G heads over a
band of feature-major encodings, then everything after it: on the CPU compiled kernels
(:func:`_heads_kernel`, :func:`_boundary_tail`; cache-resident, no allocation) around one
batched GEMM of the heads' second layers, on other torch devices as torch ops.
"""

from __future__ import annotations

import functools
import itertools
import math
from typing import NamedTuple

import numba
import numpy as np
import torch
from torch import nn

from ..errors import InputError
from .encoding import INT8_SCALE, quantize_rows

RANGE_HIDDEN = (40, 10, 10)
BOUNDARY_HIDDEN = (40, 20)
N_ORIENTATIONS = 4
TARGET_CLIP_MM = 15.0
# The arithmetic of the first-layer GEMM (PatchNets); everything after it is float32.
PATCH_PRECISIONS = ("float32", "bfloat16", "int8")


def weights_version(*modules: nn.Module) -> tuple[tuple[int, int, int], ...]:
    """Identifies the current weights of ``modules`` without reading them: each parameter's
    identity, storage and in-place version counter (``Tensor._version``: a training step or
    ``load_state_dict`` bumps it). The one key of every cache built from weights (the patch
    kind's fused engine, the fcn kind's ONNX Runtime session)."""
    return tuple((id(p), p.data_ptr(), p._version) for m in modules for p in m.parameters())


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
                   n_bins: int) -> int:
    """Neighbours per patch (``patch_size**2 - 1``); raise InputError unless F and G fit one
    ``patch_size``/``n_bins`` encoding."""
    m = patch_size * patch_size - 1
    if range_net.n_features != 2 * m + 2 * n_bins or boundary_nets.n_features != 2 * m:
        raise InputError(f"networks ({range_net.n_features}, {boundary_nets.n_features} "
                         f"inputs) do not fit a {patch_size}x{patch_size}, {n_bins}-bin "
                         "encoding")
    return m


class FusedWeights(NamedTuple):
    """F and the four G heads laid out for inference (float32, C-contiguous numpy).

    ``nf`` = F's first hidden width (40), ``h1``, ``h2`` = a head's hidden widths (40, 20),
    ``rows = nf + heads * h1`` (200), ``M`` = neighbours per patch (120).

    Attributes:
        first: (rows, 2 M) first-layer weights of the ``[x_R x_A]`` inputs: F's, then head k's
            at rows ``nf + k h1 ..``: one GEMM gives all first-layer pre-activations.
        bias: (rows,) first-layer biases, same rows.
        table_bins: (nf, n_bins, n_bins) F's first-layer weights of the one-hot b_R and b_A
            inputs, summed: ``[j, b_R, b_A] = W[j, b_R] + W[j, b_A]``, one lookup per pixel
            and row instead of products with two one-hot vectors (or two lookups).
        f_w: (L, widest out, widest in) F's remaining L layers ``(out, in)``, zero-padded.
        f_b: (L, widest out) their biases.
        f_dims: (L + 1,) int64 widths ``[nf, .., 1]``.
        g_w2: (heads, h2, h1) the heads' second layers ``(out, in)``; g_b2: (heads, h2).
        g_w3: (heads, 2, h2) the heads' output layers ``(out, in)``; g_b3: (heads, 2).
        t_clip: float32 T, F's output scale (mm per unit of the output).
    """

    first: np.ndarray
    bias: np.ndarray
    table_bins: np.ndarray
    f_w: np.ndarray
    f_b: np.ndarray
    f_dims: np.ndarray
    g_w2: np.ndarray
    g_b2: np.ndarray
    g_w3: np.ndarray
    g_b3: np.ndarray
    t_clip: np.float32


def _np32(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().cpu().float().numpy())


def fuse_weights(range_net: RangeRecoveryNet, boundary_nets: BoundaryNets, patch_size: int,
                 n_bins: int) -> FusedWeights:
    """The package's one re-layout of the trained modules for inference (see
    :class:`FusedWeights`); raise InputError unless they fit a ``patch_size``/``n_bins``
    encoding."""
    m = _check_fusable(range_net, boundary_nets, patch_size, n_bins)
    g = boundary_nets
    w_f = _np32(range_net.layers[0].weight)
    rest = range_net.layers[1:]
    f_dims = np.array([w_f.shape[0]] + [layer.out_features for layer in rest], np.int64)
    f_w = np.zeros((len(rest), int(max(f_dims[1:].max(), 1)), int(f_dims[:-1].max())),
                   np.float32)
    f_b = np.zeros(f_w.shape[:2], np.float32)
    for i, layer in enumerate(rest):
        f_w[i, :layer.out_features, :layer.in_features] = _np32(layer.weight)
        f_b[i, :layer.out_features] = _np32(layer.bias)
    return FusedWeights(
        first=np.ascontiguousarray(np.concatenate([w_f[:, :2 * m], _np32(g.first.weight)])),
        bias=_np32(torch.cat([range_net.layers[0].bias.detach().cpu(),
                              g.first.bias.detach().cpu()])),
        table_bins=np.ascontiguousarray(w_f[:, 2 * m:2 * m + n_bins, None]
                                        + w_f[:, None, 2 * m + n_bins:]),
        f_w=f_w, f_b=f_b, f_dims=f_dims,
        g_w2=_np32(g.w2.transpose(1, 2)), g_b2=_np32(g.b2[:, 0]),
        g_w3=_np32(g.w3.transpose(1, 2)), g_b3=_np32(g.b3[:, 0]),
        t_clip=np.float32(range_net.target_clip_mm))


# ---------------------------------------------------------------------------------------------
# The first-layer GEMM


def _onednn_linear(weight: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``weight @ x`` (x feature-major, (K, n)) through oneDNN's JIT GEMM
    (``mkldnn._linear_pointwise``, which computes ``weight @ x.t().T``; the transposed view
    is read in place).

    torch's CPU ``mm`` goes to MKL, which on AMD CPUs runs about half as fast (measured on the
    benchmark's Zen 5: 105-110 vs 225-240 GFLOP/s on one core for these shapes, float32, same
    accuracy). The op is the one torch.compile emits for linear layers on CPU.
    """
    return torch.ops.mkldnn._linear_pointwise(weight, x.t(), None, "none", [], "")


def _mkl_linear(weight: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``weight @ x`` with torch.mm (other devices; fallback when oneDNN is unavailable)."""
    return torch.mm(weight, x)


def _int8_linear(weight: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``weight @ x`` of int8 operands (x feature-major), exact in int32 (``torch._int_mm``:
    oneDNN's int8 GEMM, AVX512-VNNI / AMX-INT8 where the CPU has them)."""
    return torch._int_mm(weight, x)


@functools.cache
def int8_gemm_available() -> bool:
    """Whether this torch build runs :func:`_int8_linear` here and gets the exact product
    (checked once per process)."""
    try:
        gen = torch.Generator().manual_seed(0)
        w = torch.randint(-127, 128, (24, 64), generator=gen, dtype=torch.int8)
        x = torch.randint(-127, 128, (64, 40), generator=gen, dtype=torch.int8)
        got = _int8_linear(w, x)
        return got.dtype == torch.int32 and bool(torch.equal(got.long(), w.long() @ x.long()))
    except (RuntimeError, AttributeError):   # op missing or unsupported in this build
        return False


def _pick_linear(dtype: torch.dtype) -> object:
    """oneDNN's GEMM when it runs here and agrees with ``torch.mm``, else ``torch.mm``."""
    try:
        if not torch.backends.mkldnn.is_available():
            return _mkl_linear
        gen = torch.Generator().manual_seed(0)
        w = torch.rand(24, 40, generator=gen).to(dtype)
        x = torch.rand(40, 33, generator=gen).to(dtype)
        got = _onednn_linear(w, x).float()
        want = _mkl_linear(w.float(), x.float())
        tol = 1e-4 if dtype == torch.float32 else 0.1
        if got.shape == want.shape and bool(torch.allclose(got, want, atol=tol, rtol=0)):
            return _onednn_linear
    except (RuntimeError, AttributeError):   # op missing or unsupported in this build
        pass
    return _mkl_linear


# ---------------------------------------------------------------------------------------------
# The compiled kernel of everything after the first layer (CPU)


class FrameBins(NamedTuple):
    """Per-pixel inputs of a frame besides the encoding (flat, ``H * W``).

    Attributes:
        bin_range, bin_amplitude: (H*W,) int32 one-hot bin indices.
        valid: (H*W,) bool validity.
    """

    bin_range: np.ndarray
    bin_amplitude: np.ndarray
    valid: np.ndarray


class HeadOutputs(NamedTuple):
    """Per-pixel outputs of the networks (flat, ``H * W``).

    Attributes:
        correction: (H*W,) float32 F(p) in mm.
        best: (H*W,) float32 maximum edge probability over the heads (0 at invalid pixels).
        group: (H*W,) int8 its head, first on ties (0 at invalid pixels).
        logit: (H*W,) float32 that head's logit difference ``l1 - l0`` (``best`` is its
            sigmoid; -inf at invalid pixels).
        margin: (H*W,) float32 how far the runner-up head's logit difference is below it
            (>= 0; +inf at invalid pixels): the pipeline reads how sure a reduced precision's
            group is from it.
    """

    correction: np.ndarray
    best: np.ndarray
    group: np.ndarray
    logit: np.ndarray
    margin: np.ndarray

    @classmethod
    def zeros(cls, n: int) -> HeadOutputs:
        """Outputs of n pixels."""
        return cls(np.zeros(n, np.float32), np.zeros(n, np.float32), np.zeros(n, np.int8),
                   np.zeros(n, np.float32), np.zeros(n, np.float32))


class Scratch(NamedTuple):
    """Work arrays of one worker of :meth:`PatchNets.heads` (float32; ``chunk`` pixels wide,
    or a whole band of up to ``band`` pixels).

    Attributes:
        hidden: (nf, chunk) F's first-layer activations.
        f_even, f_odd: (widest F layer, chunk) ping-pong buffers of F's layers.
        g_logits: (3, chunk) the heads' best logit difference, a head's, the runner-up's.
        joint: (chunk,) int32 the pixels' joint one-hot index ``b_R * n_bins + b_A``.
        g_in: (heads * h1 * band,) the band's G first-layer activations, head-major.
        g_out: (heads * h2 * band,) their second-layer pre-activations (one batched GEMM).
    """

    hidden: np.ndarray
    f_even: np.ndarray
    f_odd: np.ndarray
    g_logits: np.ndarray
    joint: np.ndarray
    g_in: np.ndarray
    g_out: np.ndarray


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _dense(w: np.ndarray, b: np.ndarray, n_out: int, n_in: int, src: np.ndarray,
           dst: np.ndarray, m: int, relu: bool) -> None:  # pragma: no cover
    """``dst[j, :m] = act(b[j] + sum_i w[j, i] src[i, :m])``, vectorised over pixels.

    Four output rows at a time share each load of ``src`` (1.5x faster than one row at a
    time; every output is still the same sum in the same order). Long: the 4-row body and its
    remainder loop are one unrolled piece.
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
def _range_activations(first: np.ndarray, scale: np.ndarray, c0: int, m: int, q0: int,
                       frame: FrameBins, wts: FusedWeights, hidden: np.ndarray,
                       joint: np.ndarray) -> None:  # pragma: no cover
    """F's first-layer activations ``hidden[j, :m] = relu(first[j, c0:c0 + m] * scale[j] +
    bias[j] + the one-hot lookup)``, j < nf, for pixels ``q0 .. q0 + m`` of the frame.
    ``first`` is float32 with scale 1 (which leaves every value as it was), or the int8 GEMM's
    exact int32 sums (below 2**24 in magnitude, so exact in float32) with the weights' and
    the inputs' scales; then each of F's rows also has a residual row ``rows + j`` (scale
    ``scale[rows + j]``)."""
    nf = wts.f_dims[0]
    rows = wts.first.shape[0]
    residual = first.shape[0] > rows
    zero = np.float32(0.0)
    n_bins = wts.table_bins.shape[2]
    # one flat index per pixel: a 2-D table lookup in the loops below would not vectorise
    # (measured: 4x slower)
    for px in range(m):
        joint[px] = frame.bin_range[q0 + px] * n_bins + frame.bin_amplitude[q0 + px]
    for j in range(nf):
        src = first[j, c0:c0 + m]
        bj = wts.bias[j]
        sj = scale[j]
        dst = hidden[j]
        tb = wts.table_bins[j].reshape(n_bins * n_bins)      # a view: the table is C-ordered
        if residual:
            low = first[rows + j, c0:c0 + m]
            sl = scale[rows + j]
            for px in range(m):
                v = (np.float32(src[px]) * sj + np.float32(low[px]) * sl + bj
                     + tb[joint[px]])
                dst[px] = max(v, zero)
        else:
            for px in range(m):
                dst[px] = max(np.float32(src[px]) * sj + bj + tb[joint[px]], zero)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _boundary_activations(first: np.ndarray, scale: np.ndarray, n: int, wts: FusedWeights,
                          g_in: np.ndarray) -> None:  # pragma: no cover
    """The G heads' first-layer activations of a band's ``n`` pixels, ``g_in[j - nf, :n] =
    relu(first[j, :n] * scale[j] + bias[j])`` for the rows j >= nf (``first`` and its scales
    as in :func:`_range_activations`): whole rows, the band fits in L2."""
    nf = wts.f_dims[0]
    zero = np.float32(0.0)
    for j in range(nf, wts.first.shape[0]):
        src = first[j]
        dst = g_in[j - nf]
        bj = wts.bias[j]
        sj = scale[j]
        for px in range(n):
            dst[px] = max(np.float32(src[px]) * sj + bj, zero)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _range_chunk(wts: FusedWeights, m: int, q0: int, scratch: Scratch,
                 correction: np.ndarray) -> None:  # pragma: no cover
    """F's layers after the first on ``scratch.hidden[:nf, :m]``; F(p) in mm into
    ``correction[q0 .. q0 + m]``."""
    dims = wts.f_dims
    n_layers = dims.shape[0] - 1
    src = scratch.hidden[:dims[0]]
    for layer in range(n_layers):
        dst = scratch.f_even if layer % 2 == 0 else scratch.f_odd
        _dense(wts.f_w[layer], wts.f_b[layer], dims[layer + 1], dims[layer], src, dst, m,
               layer < n_layers - 1)
        src = dst
    out = src[0]
    for px in range(m):
        correction[q0 + px] = out[px] * wts.t_clip


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _heads_kernel(first: np.ndarray, scale: np.ndarray, n: int, start: int,
                  frame: FrameBins, wts: FusedWeights, do_f: bool, do_g: bool, out: HeadOutputs,
                  scratch: Scratch, g_in: np.ndarray) -> None:  # pragma: no cover
    """Everything of F after the first-layer GEMM, and the G heads' first-layer activations,
    for pixels ``start .. start + n`` of a frame.

    ``first`` (rows, >= n) holds the first layers' ``W x`` (F's rows first, then each G
    head's), row j in units of ``scale[j]``. The heads' activations go to ``g_in``
    (heads * h1, n) for their second layer's GEMM; then per chunk of
    ``scratch.hidden.shape[1]`` pixels (cache-resident) F's activations (scale, bias, one-hot
    term, ReLU) and its remaining layers, into ``out.correction``.
    """
    if do_g:
        _boundary_activations(first, scale, n, wts, g_in)
    if do_f:
        ch = scratch.hidden.shape[1]
        for c0 in range(0, n, ch):
            m = min(ch, n - c0)
            q0 = start + c0
            _range_activations(first, scale, c0, m, q0, frame, wts, scratch.hidden,
                               scratch.joint)
            _range_chunk(wts, m, q0, scratch, out.correction)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _boundary_tail(g_out: np.ndarray, n: int, start: int, valid: np.ndarray,
                   wts: FusedWeights, scratch: Scratch, out: HeadOutputs
                   ) -> None:  # pragma: no cover
    """The G heads after their second layer's GEMM: ``g_out`` (heads, h2, n) holds
    ``W2 h1`` of pixels ``start .. start + n``; the maximum edge probability over the heads, its
    head (first on ties), its logit difference and its margin over the runner-up into ``out``.

    A head's probability is softmax(l)[1] = sigmoid(l1 - l0), and the sigmoid is increasing, so
    the head with the largest logit difference ``d = (w3[1] - w3[0]) . relu(g + b2) + b3[1] -
    b3[0]`` is the most probable: one dot product per head and one exponential per pixel (in
    float64 then rounded, so the float32 probability is the correctly rounded one of d).
    """
    n_heads, h2, _h1 = wts.g_w2.shape
    ch = scratch.g_logits.shape[1]
    best_d = scratch.g_logits[0]
    d = scratch.g_logits[1]
    second_d = scratch.g_logits[2]
    zero = np.float32(0.0)
    for c0 in range(0, n, ch):
        m = min(ch, n - c0)
        q0 = start + c0
        for k in range(n_heads):
            bd = wts.g_b3[k, 1] - wts.g_b3[k, 0]
            for px in range(m):
                d[px] = bd
            for i in range(h2):
                src = g_out[k, i, c0:c0 + m]
                bi = wts.g_b2[k, i]
                wi = wts.g_w3[k, 1, i] - wts.g_w3[k, 0, i]
                for px in range(m):
                    d[px] += wi * max(src[px] + bi, zero)
            if k == 0:
                for px in range(m):
                    best_d[px] = d[px]
                    second_d[px] = -np.inf
                    out.group[q0 + px] = 0
                continue
            for px in range(m):
                if d[px] > best_d[px]:
                    second_d[px] = best_d[px]
                    best_d[px] = d[px]
                    out.group[q0 + px] = k
                else:
                    second_d[px] = max(second_d[px], d[px])
        for px in range(m):
            q = q0 + px
            if valid[q]:
                out.best[q] = np.float32(1.0 / (1.0 + math.exp(-np.float64(best_d[px]))))
                out.logit[q] = best_d[px]
                out.margin[q] = best_d[px] - second_d[px]
            else:
                out.best[q] = zero
                out.group[q] = 0
                out.logit[q] = -np.inf
                out.margin[q] = np.inf


# ---------------------------------------------------------------------------------------------
# The inference path


class PatchNets:
    """The package's one inference path of F and the four G heads (``pipeline.correct``).

    Per band of pixels, given their feature-major ``[x_R x_A]`` (``encoding.encode_band``):

    1. :meth:`first_layer`: one GEMM of :attr:`FusedWeights.first` against the band gives all
       200 first-layer pre-activations (oneDNN on the CPU when available, see
       :func:`_onednn_linear`; ``torch.mm`` on other devices);
    2. :meth:`heads`: the rest, from the same :class:`FusedWeights`, with one of two backends
       for a real reason (numba does not run on a GPU; torch's small-op overhead is several
       times the arithmetic on a CPU):

       * ``"numba"`` (the CPU's): :func:`_heads_kernel` (F, and the heads' first-layer
         activations), one batched GEMM of the heads' second layers over the band (torch's
         CPU GEMM; a loop kernel ran this 80 % of the work at a quarter of the speed), then
         :func:`_boundary_tail`; the kernels are vectorised over pixels in chunks that stay in
         L1/L2 and write straight into the frame's outputs;
       * ``"torch"`` (every other device's): the same operations as torch ops on the device
         (the heads as batched GEMMs), results copied into the same outputs. It agrees with
         the numba backend up to float32 summation order (the tests bound it: the same edges,
         F within 1e-3 mm); only the numba backend's output is pinned bit for bit.

    Both compute the modules' function up to float32 summation order (F within ~2e-5 mm,
    probabilities within ~1e-6 of the float64 oracle in ``test/oracles``).

    ``precision="bfloat16"`` rounds the first layers' inputs and weights to bfloat16 (float32
    accumulation): measured on the benchmark's Zen 5 (AVX512-BF16), networks 18 instead of
    24 ms of CPU per 180x140 frame, but R_F off by up to 0.1 mm and ~0.5 % of the edge pixels
    flipped (so the final range differs by tens of mm next to them): it misses the "same edges,
    1e-3 mm" agreement with the oracle that the float32 default keeps. Opt-in only. The
    pipeline recomputes G in float32 where the rounding could flip an edge decision (the
    ``logit`` and ``margin`` outputs say where; ``pipeline._Engine._recheck_unsure``).

    ``precision="int8"`` (CPU, numba backend): the band comes as int8 rows
    (``encoding.encode_band_int8``, ``rint(254 x)``), each first-layer row's weights are
    rounded to int8 on their own scale ``max |w_j| / 127`` (F's rows with a second, residual
    int8 row: :meth:`_setup_int8`), and the GEMM sums exactly in int32 (:func:`_int8_linear`);
    the kernel takes the sums back to float32 with the scales. The layers after the first stay
    float32. Opt-in; its agreement with float32 is measured in docs/performance.md.

    Args:
        range_net: the trained F.
        boundary_nets: the trained G heads.
        patch_size: P of the encoding.
        n_bins: one-hot width of the encoding.
        precision: ``"float32"``, ``"bfloat16"`` or ``"int8"`` (CPU and numba only).
        device: where the GEMM (and the torch backend) runs.
        backend: ``"numba"`` or ``"torch"``; None = numba on the CPU, torch elsewhere.
        chunk: pixels per chunk of the numba kernel.
    """

    def __init__(self, range_net: RangeRecoveryNet, boundary_nets: BoundaryNets,
                 patch_size: int, n_bins: int, precision: str = "float32",
                 device: torch.device | str = "cpu", backend: str | None = None,
                 chunk: int = 256) -> None:
        if precision not in PATCH_PRECISIONS:
            raise InputError(f"precision must be one of {PATCH_PRECISIONS}, got {precision!r}")
        self.device = torch.device(device)
        self.backend = backend or ("numba" if self.device.type == "cpu" else "torch")
        if self.backend not in ("numba", "torch") or (
                self.backend == "numba" and self.device.type != "cpu"):
            raise InputError(f"backend must be 'numba' (CPU) or 'torch', got {backend!r} on "
                             f"{self.device}")
        self.weights = fuse_weights(range_net, boundary_nets, patch_size, n_bins)
        self.precision = precision
        self.rows, self.n_inputs = self.weights.first.shape
        self.g_w2 = torch.from_numpy(self.weights.g_w2)      # (heads, h2, h1), shares memory
        self.chunk = int(chunk)
        # The kernel's per-row unit of the GEMM output (1: the GEMM is float).
        self.scale = np.ones(self.rows, np.float32)
        if precision == "int8":
            self._setup_int8()
            return
        self.dtype = torch.bfloat16 if precision == "bfloat16" else torch.float32
        self.weight = torch.from_numpy(self.weights.first).to(self.device, self.dtype)
        self.linear = _pick_linear(self.dtype) if self.device.type == "cpu" else _mkl_linear
        if self.backend == "torch":
            self.on_device = FusedWeights(*(torch.from_numpy(np.asarray(v)).to(self.device)
                                            for v in self.weights))

    def _setup_int8(self) -> None:
        """Per-row symmetric int8 weights, a residual int8 row for each of F's rows, and the
        scales that undo the roundings.

        F's first layer gets its weights' rounding residual as a second int8 row (step / 254,
        so the weights are kept to ~15 bits): its error moves R_F directly, while a G head's
        is read only through a threshold. Measured on simulated 320x240 frames with the shipped
        weights: R_F off by > 0.5 mm on 0.15-0.23 % of the pixels with one row, <0.01 % with
        two (docs/performance.md); it costs 40 of 240 GEMM rows.
        """
        if self.backend != "numba":
            raise InputError("precision 'int8' runs on the CPU (numba backend) only, got "
                             f"backend {self.backend!r} on {self.device}")
        if not int8_gemm_available():
            raise InputError("precision 'int8' needs torch._int_mm (oneDNN's int8 GEMM), which "
                             "this torch build does not run here; use float32 or bfloat16")
        first = self.weights.first.astype(np.float64)
        step = np.abs(first).max(axis=1) / 127.0
        step[step == 0] = 1.0                      # an all-zero row stays zero at any scale
        high = np.rint(first / step[:, None])
        nf = int(self.weights.f_dims[0])
        step_low = step[:nf] / 254.0               # |residual| <= step / 2 -> |q| <= 127
        low = np.rint((first[:nf] - high[:nf] * step[:nf, None]) / step_low[:, None])
        self.dtype = torch.int8
        self.weight = torch.from_numpy(np.concatenate([high, low]).astype(np.int8))
        self.scale = (np.concatenate([step, step_low]) / INT8_SCALE).astype(np.float32)
        self.linear = _int8_linear

    def scratch(self, band: int) -> Scratch | None:
        """Work arrays of one worker for :meth:`heads` on bands of up to ``band`` pixels
        (allocate once, reuse every band)."""
        if self.backend != "numba":
            return None
        ch = self.chunk
        wts = self.weights
        widest = wts.f_w.shape[1]
        n_heads, h2, h1 = wts.g_w2.shape
        return Scratch(np.empty((int(wts.f_dims[0]), ch), np.float32),
                       np.empty((widest, ch), np.float32), np.empty((widest, ch), np.float32),
                       np.empty((3, ch), np.float32), np.empty(ch, np.int32),
                       np.empty(n_heads * h1 * band, np.float32),
                       np.empty(n_heads * h2 * band, np.float32))

    def first_layer(self, x: torch.Tensor) -> torch.Tensor:
        """First-layer ``W x`` (no bias) of n pixels, row j in units of ``scale[j]``.

        Args:
            x: (2 M, n) feature-major ``[x_R x_A]`` (contiguous, CPU;
                ``encoding.encode_band``): float32, or for ``"int8"`` already quantised
                (``encoding.encode_band_int8``); float32 inputs are then quantised here
                (``encoding.quantize_rows``).

        Returns:
            (rows, n) tensor on the device (channel-major): float32, or int32 for ``"int8"``.
        """
        if self.precision != "int8":
            return self.linear(self.weight, x.to(self.device, self.dtype)).float()
        if x.dtype != torch.int8:
            xf = np.ascontiguousarray(x.numpy(), np.float32)
            if xf.size and not np.abs(xf).max() <= 0.5 + 1e-6:
                raise InputError("int8 inputs must be encoding rows, within [-0.5, 0.5]; got "
                                 f"values up to {np.abs(xf).max():.3g}")
            q = np.empty(xf.shape, np.int8)
            quantize_rows(xf, q)
            x = torch.from_numpy(q)
        return self.linear(self.weight, x)

    def heads(self, first: torch.Tensor, n: int, start: int, frame: FrameBins, do_f: bool,
              do_g: bool, out: HeadOutputs, scratch: Scratch | None) -> None:
        """Everything after the first layer for pixels ``start .. start + n`` (flat indices).

        Args:
            first: :meth:`first_layer` of those pixels.
            n, start: pixel count and first flat index.
            frame: the frame's bins and validity.
            do_f, do_g: run F / the G heads.
            out: the frame's outputs, written at those pixels.
            scratch: from :meth:`scratch`.
        """
        if self.backend == "numba":
            wts = self.weights
            n_heads, h2, h1 = wts.g_w2.shape
            g_in = scratch.g_in[:n_heads * h1 * n].reshape(n_heads * h1, n)
            _heads_kernel(first.numpy(), self.scale, n, start, frame, wts, do_f, do_g, out,
                          scratch, g_in)
            if do_g:
                # the heads' second layer is 80 % of the arithmetic after the first: one
                # batched GEMM per band (oneDNN/MKL) instead of the kernel's loops (measured,
                # 320x240 on one thread: 4 against 16 ms per frame)
                g_out = scratch.g_out[:n_heads * h2 * n].reshape(n_heads, h2, n)
                torch.bmm(self.g_w2, torch.from_numpy(g_in).view(n_heads, h1, n),
                          out=torch.from_numpy(g_out))
                _boundary_tail(g_out, n, start, frame.valid, wts, scratch, out)
        else:
            _heads_torch(self.on_device, first, slice(start, start + n), frame, do_f, do_g,
                         out)


def _heads_torch(wts: FusedWeights, first: torch.Tensor, pixels: slice, frame: FrameBins,
                 do_f: bool, do_g: bool, out: HeadOutputs) -> None:
    """:func:`_heads_kernel`'s operations as torch ops on ``first``'s device.

    Args:
        wts: :class:`FusedWeights` as tensors on that device.
        first: (rows, n) float32 first-layer ``W x`` of the pixels (overwritten).
        pixels: their flat indices in the frame, a slice of length n.
        frame, do_f, do_g, out: as :meth:`PatchNets.heads` (the group is the first maximum on
            ties, as ``torch.max`` documents and the kernel does).
    """
    dev = first.device
    nf = int(wts.f_dims[0])
    bins_r = torch.from_numpy(frame.bin_range[pixels]).to(dev).long()
    bins_a = torch.from_numpy(frame.bin_amplitude[pixels]).to(dev).long()
    with torch.no_grad():
        h = first.add_(wts.bias[:, None])
        h[:nf].add_(wts.table_bins[:, bins_r, bins_a])
        h.relu_()
        if do_f:
            x = h[:nf]
            dims = wts.f_dims.tolist()
            for i in range(len(dims) - 1):
                x = torch.addmm(wts.f_b[i, :dims[i + 1], None],
                                wts.f_w[i, :dims[i + 1], :dims[i]], x)
                if i < len(dims) - 2:
                    x.relu_()
            out.correction[pixels] = (x[0] * wts.t_clip).cpu().numpy()
        if do_g:
            n_heads, _h2, h1 = wts.g_w2.shape
            hg = h[nf:].reshape(n_heads, h1, -1)
            hg = torch.baddbmm(wts.g_b2[:, :, None], wts.g_w2, hg).relu_()
            logits = torch.baddbmm(wts.g_b3[:, :, None], wts.g_w3, hg)
            diffs = logits[:, 1] - logits[:, 0]                        # (heads, n)
            top = diffs.topk(min(2, n_heads), dim=0).values
            best = (1.0 / (1.0 + torch.exp(-top[0].double()))).float()
            valid = torch.from_numpy(frame.valid[pixels]).to(dev)
            out.best[pixels] = torch.where(valid, best, 0.0).cpu().numpy()
            # the first maximum on ties, as the kernel (topk's order on ties is unspecified)
            group = diffs.argmax(dim=0)
            out.group[pixels] = torch.where(valid, group, 0).to(torch.int8).cpu().numpy()
            out.logit[pixels] = torch.where(valid, top[0], -torch.inf).cpu().numpy()
            margin = top[0] - top[1] if n_heads > 1 else torch.full_like(top[0], torch.inf)
            out.margin[pixels] = torch.where(valid, margin, torch.inf).cpu().numpy()
