"""Exact slow reference of the fcn kind's gated kernel mean (``fcn.kernel_mean_shift``): one
neighbour at a time on (B, H, W) planes, differentiable by torch's autograd."""

from __future__ import annotations

import math

import torch
from torch.nn import functional as tnf


def kernel_mean_shift_reference(logits: torch.Tensor, range_m: torch.Tensor,
                                valid: torch.Tensor, gate_mm: float) -> torch.Tensor:
    """``Σ_q w_q R(q) - R(p)`` (mm), w the softmax of ``logits`` (B, k², H, W) over the
    neighbours that are valid, inside the frame and within ``gate_mm`` of p; 0 at invalid p."""
    k = math.isqrt(logits.shape[1])
    pad = k // 2
    h, w = range_m.shape[-2:]
    r_mm = range_m.double() * 1000.0
    r_pad = tnf.pad(r_mm, (pad, pad, pad, pad))
    v_pad = tnf.pad(valid.double(), (pad, pad, pad, pad)) > 0
    lg = logits.double()
    top = lg.amax(dim=1)
    num = torch.zeros_like(r_mm)
    den = torch.zeros_like(r_mm)
    for i in range(k * k):
        dy, dx = divmod(i, k)
        diff = r_pad[:, dy:dy + h, dx:dx + w] - r_mm
        near = v_pad[:, dy:dy + h, dx:dx + w] & (diff.abs() <= gate_mm)
        weight = torch.exp(lg[:, i] - top) * near
        num = num + weight * diff
        den = den + weight
    return num / den.clamp(min=1e-30) * valid.double()
