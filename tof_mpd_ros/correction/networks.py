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
"""

from __future__ import annotations

import itertools
import math

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
        if precision not in ("float32", "bfloat16"):
            raise InputError(f"precision must be 'float32' or 'bfloat16', got {precision!r}")
        m = patch_size * patch_size - 1
        if range_net.n_features != 2 * m + 2 * n_bins or boundary_nets.n_features != 2 * m:
            raise InputError(f"networks ({range_net.n_features}, {boundary_nets.n_features} "
                             f"inputs) do not fit a {patch_size}x{patch_size}, {n_bins}-bin "
                             "encoding")
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
