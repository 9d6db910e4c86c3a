"""The second model kind: a fully-convolutional residual network with per-pixel uncertainty.

Why a U-Net. F and G see an 11×11 patch, about 15 mm at 300 mm, but with faithful light
transport a box's side face is lit from table 100+ mm away. A U-Net reaches far at little cost:
each level halves the resolution, so five levels of two 3×3 convolutions see about 140 px
(measured by :func:`receptive_field_px`) while most of the arithmetic stays at the coarse
levels; the skip connections carry the full-resolution detail back to every pixel. A
kernel-predicting network would have to predict kernels that large, and a plain dilated stack
aliases on the ToF's 1-px structures (flying pixels).

Why a predicted kernel plus a residual. Two errors of different reach are corrected. The
noise (σ 2–9 mm per pixel on the simulated cell, most on dark pixels) needs an edge-aware mean
over a few neighbours on the same surface; multipath needs the far context. So the output is
``Σ_q w_q(p) R(q) + Δ(p)``: a convex combination of the calibrated ranges of the k × k
neighbourhood of p (``kernel_px``, 5 by default; weights a softmax over its *valid* pixels,
predicted per pixel, as in kernel-predicting denoisers) plus an additive correction Δ from the
whole receptive field. The weights are the network's own choice of the pixels on p's surface:
a pure residual (``kernel_px = 1``) would have to carry the mean of the neighbours' noise
through the thin full-resolution level, which trains slowly and poorly (measured,
``docs/method.md`` §9). A neighbour farther than ``kernel_gate_mm`` in range from p gets no
weight, so no depth step larger than that is blurred, whatever the network predicts (tested); a
flying pixel (a mix of both sides, far from both) keeps its own range and gets a large predicted
σ where the network is unsure of its side (beyond ``max_sigma_mm``); the output then takes the
side nearer in range from its sure neighbours (:func:`resolve_to_a_side`), or invalidates it
when it has none.

Why σ. The network predicts the correction's mean and standard deviation, trained with the
Gaussian negative log-likelihood (a proper scoring rule: the expected loss is lowest at the true
σ), so σ means millimetres of expected error and can be checked: the fraction of pixels with
``|error| <= k σ`` should be 68 / 95 / 99.7 % for k = 1, 2, 3.

Inputs, per pixel (0 where the measurement is invalid; the frame is mirrored out to a multiple
of ``2^(levels - 1)``, :func:`pad_to_multiple`): the calibrated range relative to the frame's
median (per 100 mm), the absolute range (m: multipath depends on scale), the log amplitude
relative to the frame's median, the validity mask, the absolute log amplitude (per
``LOG_AMPLITUDE_SCALE``: the noise and a dark surface's bias depend on the light a pixel
receives, in the camera's own units) and the local range detail (the range minus the mean of
its valid 7 × 7 neighbours, clipped to ±50 mm, per 50 mm: the millimetre structure the noise
lives in, at a scale the first layer sees).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import cv2
import numba
import numpy as np
import torch
from torch import nn
from torch.nn import functional as tnf

from ..calibration.intrinsic import IntrinsicCalibration, valid_measurement
from ..errors import InputError
from ..thread_pools import run_chunks
from . import fcn_onnx

#: input channels of :func:`fcn_inputs`
N_INPUTS = 6
#: range units of the relative-range channel, mm
RANGE_SCALE_MM = 100.0
#: units of the absolute log-amplitude channel (ln of sensor units)
LOG_AMPLITUDE_SCALE = 8.0
#: side of the neighbourhood of the local-detail channel, px
DETAIL_PX = 7
#: the local-detail channel is clipped to +-this, mm, and given in these units
DETAIL_CLIP_MM = 50.0


@dataclass(frozen=True)
class FCNArchitecture:
    """Shape of :class:`ResidualFCN` and its output scaling, stored in the weights file.

    Attributes:
        widths: channels per level, finest first; ``len(widths)`` levels, each but the last
            followed by a stride-2 downsampling.
        correction_scale_mm: the correction output unit, mm (keeps the last layer well scaled).
        sigma_floor_mm: smallest σ the network can predict, mm (no pixel is certain to 0 mm).
        sigma_scale_mm: σ = floor + scale · softplus(output), mm.
        kernel_px: side k of the predicted neighbourhood kernel (odd; 1 = the pixel's own
            range plus the correction only).
        kernel_gate_mm: neighbours farther than this in range from the pixel get no weight in
            the kernel, mm.
    """

    widths: tuple[int, ...] = (8, 16, 32, 48, 64)
    correction_scale_mm: float = 10.0
    sigma_floor_mm: float = 0.3
    sigma_scale_mm: float = 5.0
    kernel_px: int = 5
    kernel_gate_mm: float = 30.0

    def __post_init__(self) -> None:
        if len(self.widths) < 2 or any(int(w) < 1 for w in self.widths):
            raise InputError(f"FCN widths need >= 2 levels of >= 1 channel, got {self.widths}")
        if not (self.correction_scale_mm > 0 and self.sigma_floor_mm > 0
                and self.sigma_scale_mm > 0 and self.kernel_gate_mm > 0):
            raise InputError(f"FCN output scales must be > 0: {self}")
        if int(self.kernel_px) < 1 or int(self.kernel_px) % 2 == 0:
            raise InputError(f"FCN kernel_px must be odd and >= 1, got {self.kernel_px}")
        object.__setattr__(self, "widths", tuple(int(w) for w in self.widths))
        object.__setattr__(self, "kernel_px", int(self.kernel_px))

    @property
    def multiple(self) -> int:
        """Frames are padded to a multiple of this many pixels per axis."""
        return 2 ** (len(self.widths) - 1)

    def as_dict(self) -> dict[str, Any]:
        return {**asdict(self), "widths": list(self.widths)}


def _block(c_in: int, c_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, 3, padding=1), nn.ReLU(inplace=True),
                         nn.Conv2d(c_out, c_out, 3, padding=1), nn.ReLU(inplace=True))


class ResidualFCN(nn.Module):
    """U-Net: inputs (B, 6, H, W) -> (correction mm, σ mm), each (B, H, W).

    The correction is relative to the pixel's own range: ``Σ_q w_q R(q) + Δ - R(p)`` (module
    docstring), with R read back from the inputs' absolute-range plane.

    H and W must be multiples of ``architecture.multiple`` (:func:`fcn_inputs` pads).

    Args:
        architecture: widths and output scales.
        generator: seeds the initialisation (None: torch's global generator).
    """

    def __init__(self, architecture: FCNArchitecture | None = None,
                 generator: torch.Generator | None = None) -> None:
        super().__init__()
        arch = architecture or FCNArchitecture()
        self.architecture = arch
        w = arch.widths
        self.encoders = nn.ModuleList(
            [_block(N_INPUTS if i == 0 else w[i - 1], w[i]) for i in range(len(w))])
        self.downs = nn.ModuleList(
            [nn.Conv2d(w[i], w[i], 3, stride=2, padding=1) for i in range(len(w) - 1)])
        self.decoders = nn.ModuleList(
            [_block(w[i] + w[i + 1], w[i]) for i in range(len(w) - 1)])
        self.head = nn.Conv2d(w[0], 2 + (arch.kernel_px ** 2 if arch.kernel_px > 1 else 0), 1)
        if generator is not None:
            self._init(generator)

    def _init(self, generator: torch.Generator) -> None:
        """Kaiming-uniform weights (torch's Conv2d default) drawn from ``generator``."""
        with torch.no_grad():
            for m in self.modules():
                if isinstance(m, nn.Conv2d):
                    fan_in = m.in_channels * m.kernel_size[0] * m.kernel_size[1]
                    bound = 1.0 / math.sqrt(fan_in)
                    m.weight.uniform_(-bound, bound, generator=generator)
                    m.bias.uniform_(-bound, bound, generator=generator)

    def raw(self, x: torch.Tensor) -> torch.Tensor:
        """(B, 2 [+ k²], H, W) unscaled outputs of ``x`` (B, 6, H, W): correction, σ and the
        kernel's logits."""
        skips = []
        for i, enc in enumerate(self.encoders):
            x = enc(x)
            if i < len(self.downs):
                skips.append(x)
                x = self.downs[i](x)
        for i in reversed(range(len(self.decoders))):
            x = tnf.interpolate(x, size=skips[i].shape[-2:], mode="bilinear",
                                align_corners=False)
            x = self.decoders[i](torch.cat([skips[i], x], dim=1))
        # the 1 x 1 head as one matrix product over the pixels' channel vectors: the same
        # arithmetic as the convolution, which oneDNN ran at ~1 GFLOP/s on 8 input channels
        # (2.5 ms of a 24 ms 320 x 240 pass). Channel-major out, read from channels-last in
        # place: the kernel mean then runs over contiguous rows of each output plane
        b, c, h, w = x.shape
        pixels = x.permute(0, 2, 3, 1).reshape(b, h * w, c)
        weight = self.head.weight.flatten(1)
        out = torch.baddbmm(self.head.bias[None, :, None], weight.expand(b, -1, -1),
                            pixels.transpose(1, 2))
        return out.view(b, -1, h, w)

    def forward(self, x: torch.Tensor, size: tuple[int, int] | None = None
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """(correction mm, σ mm), each (B, h, w) float32: the top-left ``size`` = (h, w) of
        the padded input (its whole extent if None), see :meth:`scale`."""
        out = self.raw(x)
        if size is not None:
            h, w = size
            out, x = out[..., :h, :w], x[..., :h, :w]
        return self.scale(out, x)

    def scale(self, out: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(correction mm, σ mm) of the raw outputs ``out`` (B, 2 [+ k²], H, W) of the inputs
        ``x``; in float32 whatever precision ``out`` was computed in. Give both without the
        padding: the kernel then takes no neighbour from beyond the frame (mirrored pixels
        would be counted twice), as on a training crop's border."""
        a = self.architecture
        out = out.float()
        sigma = a.sigma_floor_mm + a.sigma_scale_mm * tnf.softplus(out[:, 1])
        corr = a.correction_scale_mm * out[:, 0]
        if a.kernel_px > 1:
            corr = corr + kernel_mean_shift(out[:, 2:], x[:, 1].float(), x[:, 3].float(),
                                            a.kernel_gate_mm)
        return corr, sigma


def kernel_mean_shift(logits: torch.Tensor, range_m: torch.Tensor, valid: torch.Tensor,
                      gate_mm: float) -> torch.Tensor:
    """``Σ_q w_q R(q) - R(p)``, mm: the predicted kernel's weighted mean of the neighbourhood's
    ranges, relative to the pixel's own; differentiable in ``logits``.

    The weights are a softmax of the logits over the *gated* neighbours: valid, inside the
    frame, and within ``gate_mm`` in range of p (the pixel itself always is, for a valid p).

    Args:
        logits: (B, k², H, W) float32 kernel logits, row-major over the k × k neighbourhood
            (any memory layout; the forward pass reads it channel-major).
        range_m: (B, H, W) float32 range, m (0 where invalid).
        valid: (B, H, W) float32 1 where the range is valid.
        gate_mm: neighbours farther than this in range get no weight, mm.

    Returns:
        (B, H, W) float32, mm; 0 on invalid pixels.

    Why a compiled kernel on the CPU. As tensor operations, one neighbour at a time, this was
    ~200 small operations per frame, each a parallel region that wakes the OpenMP threads:
    31 ms of a 62 ms 320 × 240 frame, more than the U-Net; on (B, H, W, k, k) windows
    (:func:`_kernel_mean_shift_torch`) 13–19 ms; one pass per pixel in numba 5.5 ms; torch's
    exponentials of the channel-major logits, then a numba pass one neighbour at a time over
    whole rows (:func:`_shift_rows`, vectorised), 2.8 ms (measured on the Intel Xeon pair,
    2 threads). The window formulation stays for other devices; the tests hold both to a
    per-neighbour reference.
    """
    if logits.device.type != "cpu":
        return _kernel_mean_shift_torch(logits, range_m, valid, gate_mm)
    return _KernelMeanShift.apply(logits, range_m, valid, float(gate_mm))


def _kernel_mean_shift_torch(logits: torch.Tensor, range_m: torch.Tensor, valid: torch.Tensor,
                             gate_mm: float) -> torch.Tensor:
    """:func:`kernel_mean_shift` as tensor operations on (B, H, W, k, k) windows (any device)."""
    k = math.isqrt(logits.shape[1])
    pad = k // 2
    r_mm = range_m * 1000.0
    windows = tnf.pad(torch.stack([r_mm, valid], 1), (pad, pad, pad, pad)
                      ).unfold(2, k, 1).unfold(3, k, 1)           # (B, 2, H, W, k, k) views
    diff = windows[:, 0] - r_mm[..., None, None]
    near = (windows[:, 1] > 0) & (diff.abs() <= gate_mm)
    lg = logits.permute(0, 2, 3, 1).unflatten(-1, (k, k))
    # the shift by the maximum of all k² logits keeps exp <= 1 (as in _pixel_shift)
    weight = torch.exp(lg - lg.amax(dim=(-2, -1), keepdim=True)) * near
    num = (weight * diff).sum(dim=(-2, -1))
    return num / weight.sum(dim=(-2, -1)).clamp(min=1e-30) * valid


class _KernelMeanShift(torch.autograd.Function):
    """:func:`kernel_mean_shift` on the CPU: numba kernels over the frame's rows on the
    package's worker threads; the gradient reaches the logits only (the ranges are data)."""

    @staticmethod
    def forward(ctx: Any, logits: torch.Tensor, range_m: torch.Tensor, valid: torch.Tensor,
                gate_mm: float) -> torch.Tensor:
        r_pad, v_pad = _padded_planes(logits, range_m, valid)
        lg = logits.detach().float()
        # the softmax's exponentials for every pixel at once, channel-major: torch's exp is
        # vectorised, numba's (no SVML) one libm call per neighbour (2/3 of the old kernel)
        weights = torch.exp(lg - lg.amax(dim=1, keepdim=True)).contiguous()
        out = np.zeros(weights.shape[:1] + weights.shape[2:], np.float32)
        _run_rows(out.shape[0] * out.shape[1], _shift_rows, weights.numpy(), r_pad, v_pad,
                  np.float32(gate_mm), out)
        ctx.save_for_backward(logits)
        ctx.padded = r_pad, v_pad   # data, not tensors: built once for both passes
        ctx.gate_mm = gate_mm
        return torch.from_numpy(out)

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        (logits,) = ctx.saved_tensors
        nhwc = _nhwc(logits)
        r_pad, v_pad = ctx.padded
        g = np.ascontiguousarray(grad.detach().float().numpy())
        out = np.zeros(nhwc.shape, np.float32)
        _run_rows(g.shape[0] * g.shape[1], _gradient_rows, nhwc, r_pad, v_pad,
                  np.float32(ctx.gate_mm), g, out)
        return torch.from_numpy(out).permute(0, 3, 1, 2), None, None, None


def _padded_planes(logits: torch.Tensor, range_m: torch.Tensor, valid: torch.Tensor
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The kernels' (B, H + 2p, W + 2p) float32 range (mm) and validity, zero beyond the
    frame (p = k // 2 of the (B, k², H, W) ``logits``)."""
    pad = math.isqrt(logits.shape[1]) // 2
    width = ((0, 0), (pad, pad), (pad, pad))
    r_pad = np.pad(range_m.detach().float().numpy() * np.float32(1000.0), width)
    v_pad = np.pad(valid.detach().float().numpy(), width)
    return r_pad, v_pad


def _nhwc(logits: torch.Tensor) -> np.ndarray:
    """(B, H, W, k²) float32 view of (B, k², H, W) float32 logits, any layout (no copy)."""
    return logits.detach().float().permute(0, 2, 3, 1).numpy()


def _run_rows(n_rows: int, kernel: Any, *args: Any) -> None:
    """``kernel`` (:func:`_shift_rows` or :func:`_gradient_rows`) over ``n_rows`` frame rows,
    interleaved over torch's thread count."""
    workers = torch.get_num_threads()
    run_chunks("fcn-kernel", workers, kernel, min(n_rows, 4 * workers), *args)


@numba.njit(cache=True, nogil=True)
def _shift_rows(first: int, stride: int, n_chunks: int, weights: np.ndarray, r_pad: np.ndarray,
                v_pad: np.ndarray, gate: np.float32, shift_out: np.ndarray) -> None:
    """:func:`kernel_mean_shift` (forward) on every ``stride``-th chunk of rows from ``first``
    (chunk c holds rows c, c + n_chunks, ... of the B·H rows), given ``weights`` (B, k², H, W)
    float32, the exponentials of the logits less each pixel's largest. One neighbour at a
    time over a whole row, so every inner loop runs over contiguous pixels and vectorises
    (the gate is a select, not a branch); per pixel the sums of :func:`_pixel_shift` in its
    order, normalised once at the end (``num / den``)."""
    n_frames, n, h, w = weights.shape
    k = int(math.sqrt(n) + 0.5)
    pad = k // 2
    num = np.empty(w, np.float32)
    den = np.empty(w, np.float32)
    for c in range(first, n_chunks, stride):
        for row in range(c, n_frames * h, n_chunks):
            b, y = row // h, row % h
            r0 = r_pad[b, y + pad, pad:pad + w]
            num[:] = 0.0
            den[:] = 0.0
            i = 0
            for dy in range(k):
                for dx in range(k):
                    rq = r_pad[b, y + dy, dx:dx + w]
                    vq = v_pad[b, y + dy, dx:dx + w]
                    e = weights[b, i, y]
                    for x in range(w):
                        d = rq[x] - r0[x]
                        wx = e[x] if (vq[x] > 0) & (abs(d) <= gate) else np.float32(0.0)
                        num[x] += wx * d
                        den[x] += wx
                    i += 1
            v0 = v_pad[b, y + pad, pad:pad + w]
            for x in range(w):
                # the pixel itself (difference 0) is always a neighbour of a valid pixel, so
                # den > 0; should every kept weight underflow, the pixel keeps its own range
                shift = num[x] / max(den[x], np.float32(1e-30))
                shift_out[b, y, x] = shift if v0[x] > 0 else np.float32(0.0)


@numba.njit(cache=True, nogil=True, inline="always")
def _pixel_shift(nhwc: np.ndarray, r_pad: np.ndarray, v_pad: np.ndarray, gate: np.float32,
                 k: int, b: int, y: int, x: int, weight: np.ndarray, diff: np.ndarray) -> float:
    """The kernel mean's shift of pixel (b, y, x), mm; fills ``weight`` (the softmax over the
    gated neighbours, 0 for the others) and ``diff`` (neighbour - pixel, mm)."""
    n = k * k
    r0 = r_pad[b, y + k // 2, x + k // 2]
    top = nhwc[b, y, x, 0]
    for i in range(1, n):
        top = max(top, nhwc[b, y, x, i])
    den = np.float32(0.0)
    i = 0
    for dy in range(k):           # nested, not divmod(i, k): two divisions per neighbour
        for dx in range(k):       # cost as much as the rest of its work
            d = r_pad[b, y + dy, x + dx] - r0
            diff[i] = d
            if v_pad[b, y + dy, x + dx] > 0 and abs(d) <= gate:
                weight[i] = np.exp(nhwc[b, y, x, i] - top)
                den += weight[i]
            else:
                weight[i] = 0.0
            i += 1
    # the pixel itself (difference 0) is always a neighbour of a valid pixel, so den > 0;
    # should every kept logit lie ~87 below an excluded one, the weights underflow and the
    # pixel keeps its own range (shift 0): the safe answer
    inv = np.float32(1.0) / max(den, np.float32(1e-30))   # one division, not k²
    shift = np.float32(0.0)
    for i in range(n):
        weight[i] *= inv
        shift += weight[i] * diff[i]
    return shift


@numba.njit(cache=True, nogil=True)
def _gradient_rows(first: int, stride: int, n_chunks: int, nhwc: np.ndarray, r_pad: np.ndarray,
                   v_pad: np.ndarray, gate: np.float32, grad: np.ndarray,
                   grad_out: np.ndarray) -> None:
    """The gradient of :func:`kernel_mean_shift` in the logits, (B, H, W, k²) into
    ``grad_out``, given ``grad`` (B, H, W) and the logits ``nhwc`` (B, H, W, k²), on every
    ``stride``-th chunk of rows from ``first`` (as :func:`_shift_rows`): ∂shift/∂l_i =
    w_i (d_i - shift) at a valid pixel, 0 elsewhere."""
    n_frames, h, w, n = nhwc.shape
    k = int(math.sqrt(n) + 0.5)
    pad = k // 2
    weight = np.empty(n, np.float32)
    diff = np.empty(n, np.float32)
    for c in range(first, n_chunks, stride):
        for row in range(c, n_frames * h, n_chunks):
            b, y = row // h, row % h
            for x in range(w):
                if v_pad[b, y + pad, x + pad] <= 0 or grad[b, y, x] == 0:
                    continue
                shift = _pixel_shift(nhwc, r_pad, v_pad, gate, k, b, y, x, weight, diff)
                for i in range(n):
                    grad_out[b, y, x, i] = grad[b, y, x] * weight[i] * (diff[i] - shift)


def _median_per_frame(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(B, 1, 1) median of each frame's valid values (0 for a frame with none)."""
    out = np.zeros((values.shape[0], 1, 1), np.float32)
    for b in range(values.shape[0]):
        if valid[b].any():
            out[b] = np.median(values[b][valid[b]])
    return out


def fcn_inputs(calibrated_mm: np.ndarray, amplitude: np.ndarray, multiple: int
               ) -> tuple[torch.Tensor, np.ndarray]:
    """The network's input planes of a batch of frames.

    Args:
        calibrated_mm: (B, H, W) float32 calibrated range, mm, NaN = invalid.
        amplitude: (B, H, W) float32 amplitude, sensor units.
        multiple: pad H and W up to a multiple of this.

    Returns:
        ``(x, valid)``: x (B, 6, H', W') float32 (mirrored out at the bottom and right), valid
        (B, H, W) bool.
    """
    r = np.asarray(calibrated_mm, np.float32)
    a = np.asarray(amplitude, np.float32)
    valid = valid_measurement(r, a)
    with np.errstate(invalid="ignore", divide="ignore"):
        log_a = np.where(valid, np.log(np.where(valid, a, 1.0)), 0.0).astype(np.float32)
        r0 = np.where(valid, r, 0.0).astype(np.float32)
    rel = (r0 - _median_per_frame(r0, valid)) / RANGE_SCALE_MM
    v = valid.astype(np.float32)
    planes = np.stack([np.where(valid, rel, 0.0), r0 / 1000.0,
                       np.where(valid, log_a - _median_per_frame(log_a, valid), 0.0),
                       v, log_a / LOG_AMPLITUDE_SCALE, _local_detail(r0, v)],
                      axis=1).astype(np.float32, copy=False)
    return pad_to_multiple(torch.from_numpy(planes), multiple), valid


def pad_to_multiple(x: torch.Tensor, multiple: int) -> torch.Tensor:
    """(B, C, H', W'): ``x`` (B, C, H, W) extended at the bottom and right to multiples of
    ``multiple`` by mirroring its last rows and columns.

    Why mirrored, not zeros: the network trains on crops that need no padding, so a band of
    zeros (an invalid stripe it has never seen) at inference bent its coarse levels: with
    zeros, the last 20 columns of a 180-px-wide frame (12 padded) were within 5 mm on 13–43 %
    of pixels against 95 % mid-frame (MD-Test, docs/method.md §9). A mirror looks like scene.
    """
    h, w = x.shape[-2:]
    ph, pw = -h % multiple, -w % multiple
    if not (ph or pw):
        return x
    # "reflect" needs the pad smaller than the side; a tiny frame falls back to repetition
    mode = "reflect" if ph < h and pw < w else "replicate"
    return tnf.pad(x, (0, pw, 0, ph), mode=mode)


def _box_mean(plane: np.ndarray) -> np.ndarray:
    """(H, W) float32 mean over each pixel's ``DETAIL_PX``² window of ``plane``, zeros beyond
    the frame included (OpenCV's running-sum box filter: 0.3 against torch's two pooling passes'
    1.8 ms per 320 x 240 frame, measured on the Intel Xeon pair)."""
    return cv2.boxFilter(plane, -1, (DETAIL_PX, DETAIL_PX), normalize=True,
                         borderType=cv2.BORDER_CONSTANT)


def _local_detail(range_mm: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(B, H, W) float32: range minus the mean of its valid ``DETAIL_PX``² neighbours, clipped
    to ±``DETAIL_CLIP_MM`` and divided by it; 0 on invalid pixels. Inputs (B, H, W) float32,
    range in mm (0 where invalid) and 1 / 0 validity."""
    out = np.empty_like(range_mm)
    for b in range(range_mm.shape[0]):
        total, count = _box_mean(range_mm[b] * valid[b]), _box_mean(valid[b])
        mean = total / np.maximum(count, np.float32(1e-6))
        out[b] = np.clip(range_mm[b] - mean, -DETAIL_CLIP_MM, DETAIL_CLIP_MM) * valid[b]
    return out / np.float32(DETAIL_CLIP_MM)


def gaussian_nll(correction_mm: torch.Tensor, sigma_mm: torch.Tensor, target_mm: torch.Tensor,
                 mask: torch.Tensor, beta: float = 0.0) -> torch.Tensor:
    """Mean Gaussian negative log-likelihood (nats per pixel) of ``target`` over ``mask``:
    ``0.5 ((t - μ) / σ)² + log σ + 0.5 log 2π``; every tensor (B, H, W).

    ``beta`` > 0 weights each pixel's term by its σ^(2 β), held constant in the gradient (the
    β-NLL of Seitzer et al. 2022): the plain NLL scales the mean's gradient by 1 / σ², so
    pixels the network is unsure of stop teaching it the correction; β = 0.5 undoes half of
    that. A positive weight that the gradient does not see leaves each pixel's optimum at its
    true mean and σ, so the σ it learns is still the likelihood's."""
    t = torch.where(mask, target_mm, torch.zeros_like(target_mm))
    z = (t - correction_mm) / sigma_mm
    nll = 0.5 * z.square() + torch.log(sigma_mm) + 0.5 * math.log(2 * math.pi)
    if beta:
        nll = nll * sigma_mm.detach() ** (2 * beta)
    n = mask.sum().clamp(min=1)
    return torch.where(mask, nll, torch.zeros_like(nll)).sum() / n


@dataclass
class FCNCorrectionModel:
    """Calibration + :class:`ResidualFCN`: the ``"fcn"`` kind of correction model.

    Attributes:
        calibration: per-pixel intrinsic calibration of the crop.
        net: the network.
        max_sigma_mm: pixels whose predicted σ exceeds this are unsure: the output gives
            them the range of the sure neighbour nearest in range (:func:`resolve_to_a_side`),
            NaN when no neighbour is sure.
        metadata: provenance (training data digest, config, history summary...).
    """

    calibration: IntrinsicCalibration
    net: ResidualFCN
    max_sigma_mm: float = 20.0
    metadata: dict[str, Any] = field(default_factory=dict)

    kind = "fcn"

    def __post_init__(self) -> None:
        if not self.max_sigma_mm > 0:
            raise InputError(f"max_sigma_mm must be > 0, got {self.max_sigma_mm}")

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the frames this model corrects."""
        return self.calibration.shape

    @property
    def architecture(self) -> FCNArchitecture:
        return self.net.architecture

    @classmethod
    def untrained(cls, calibration: IntrinsicCalibration,
                  architecture: FCNArchitecture | None = None, *, seed: int = 0,
                  max_sigma_mm: float = 20.0) -> FCNCorrectionModel:
        """A model with a freshly initialised (seeded) network."""
        net = ResidualFCN(architecture, generator=torch.Generator().manual_seed(seed))
        return cls(calibration, net, max_sigma_mm)

    def to(self, device: torch.device | str) -> FCNCorrectionModel:
        self.net.to(device)
        return self


#: executors of the U-Net :func:`run_fcn` takes (``"auto"``: :func:`fcn_engine`)
FCN_ENGINES = ("auto", "torch", "onnxruntime")


def check_engine_name(engine: str) -> None:
    """Raise InputError unless ``engine`` is one of :data:`FCN_ENGINES`."""
    if engine not in FCN_ENGINES:
        raise InputError(f"fcn_engine must be one of {FCN_ENGINES}, got {engine!r}")


def fcn_engine(engine: str, device: torch.device | str, precision: str) -> str:
    """The executor ``run_fcn`` uses for ``engine`` on ``device`` in ``precision``:
    ``"torch"`` or ``"onnxruntime"``.

    ``"auto"`` takes ONNX Runtime where it can run the call (installed, the CPU, float32) on 2
    or more threads, else torch. Why the thread count: measured side by side on 2 Zen 4 cores
    (docs/performance.md, session 31), one frame on two threads took 14.1 against 21.6 ms at
    180×140 and 30.6 against 35.4 at 320×240 under ONNX Runtime, but on one thread each (the
    node's ``parallel_frames``) torch's oneDNN convolutions were faster (9.6 against 10.1,
    24.5 against 27.3 ms per frame).

    Raises:
        InputError: an unknown ``engine``, or ``"onnxruntime"`` where it cannot run (not
            installed, another device than the CPU, or bfloat16, which its CPU convolutions
            do not have).
    """
    check_engine_name(engine)
    possible = torch.device(device).type == "cpu" and precision == "float32"
    if engine == "onnxruntime" and not (possible and fcn_onnx.available()):
        raise InputError("engine 'onnxruntime' runs the fcn kind on the CPU in float32 only, "
                         "with onnxruntime and onnx installed (pip install onnxruntime onnx); "
                         f"asked for device {device!s}, precision {precision!r}")
    if engine == "auto":
        fast = possible and torch.get_num_threads() >= 2 and fcn_onnx.available()
        return "onnxruntime" if fast else "torch"
    return engine


@torch.inference_mode()
def run_fcn(net: ResidualFCN, calibrated_mm: np.ndarray, amplitude: np.ndarray, *,
            device: torch.device | str = "cpu", precision: str = "float32",
            engine: str = "auto") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Correction and σ of a batch of frames.

    Args:
        net: the network (put in eval mode).
        calibrated_mm: (B, H, W) float32 calibrated range, mm, NaN = invalid.
        amplitude: (B, H, W) float32 amplitude.
        device: where the network runs (it is moved there).
        precision: ``"float32"`` or ``"bfloat16"`` (the convolutions under autocast; the
            output scaling and σ stay float32).
        engine: the U-Net's executor (:func:`fcn_engine`): torch, or ONNX Runtime on
            ``torch.get_num_threads()`` threads (:mod:`.fcn_onnx`: the same graph and weights,
            outputs within 1e-5 mm of torch's).

    Returns:
        ``(correction_mm, sigma_mm, valid)``: float32 (B, H, W) (NaN on invalid pixels) and
        bool (B, H, W).
    """
    net.eval()
    dev = torch.device(device)
    if next(net.parameters()).device != dev:
        net.to(dev)
    h, w = calibrated_mm.shape[-2:]
    x, valid = fcn_inputs(calibrated_mm, amplitude, net.architecture.multiple)
    if fcn_engine(engine, dev, precision) == "onnxruntime":
        out = fcn_onnx.run_unet(net, x, torch.get_num_threads())
    else:
        # channels-last: oneDNN's direct convolutions run faster on NHWC on the CPU
        x = x.to(dev).contiguous(memory_format=torch.channels_last)
        with torch.autocast(dev.type, dtype=torch.bfloat16, enabled=precision == "bfloat16"):
            out = net.raw(x)
    corr, sigma = net.scale(out[..., :h, :w], x[..., :h, :w])
    nan = np.float32(np.nan)
    corr_np = corr.float().cpu().numpy()
    sigma_np = sigma.float().cpu().numpy()
    return (np.where(valid, corr_np, nan).astype(np.float32),
            np.where(valid, sigma_np, nan).astype(np.float32), valid)


def resolve_to_a_side(range_mm: np.ndarray, sure: np.ndarray, unsure: np.ndarray
                      ) -> np.ndarray:
    """The output range: ``range_mm`` where ``sure``; an ``unsure`` pixel (a flying pixel, most
    of them) takes the range of its sure 8-neighbour nearest to its own range, NaN when none.

    Why. A flying pixel's return mixes the surfaces its footprint straddles, which are its
    immediate neighbours, and the mixed phasor lies nearer the surface holding the larger share
    of the footprint, which is the side its centre (what a reference samples) most likely sees.
    Invalidating it is always wrong by the paper's accuracy measure; taking the nearer side is
    right about half the time (measured on MD-Test, ``docs/method.md`` §9).

    Args:
        range_mm: (B, H, W) float32 corrected range, mm, NaN = invalid.
        sure: (B, H, W) bool pixels whose range is kept.
        unsure: (B, H, W) bool pixels to resolve (disjoint from ``sure``).

    Returns:
        (B, H, W) float32, mm; NaN outside ``sure`` and the resolved ``unsure`` pixels.
    """
    out = np.where(sure, range_mm, np.nan).astype(np.float32)
    if not unsure.any():
        return out
    pad = ((0, 0), (1, 1), (1, 1))
    padded = np.pad(out, pad, constant_values=np.nan)
    # flat indices into the padded frames: one gather (about 1 ms per 320×240 frame with 3 %
    # of it unsure, measured on a loaded Zen 4 core)
    where = np.flatnonzero(np.pad(unsure, pad))
    w = padded.shape[-1]
    offsets = (np.arange(-1, 2)[:, None] * w + np.arange(-1, 2)[None, :]).ravel()
    # (n, 9) the 3 × 3 neighbourhoods; the pixel itself is NaN there (it is not sure)
    near = padded.ravel()[where[:, None] + offsets]
    dist = np.abs(near - range_mm[unsure][:, None])  # the same C order as ``where``
    dist[~np.isfinite(dist)] = np.inf
    out[unsure] = near[np.arange(where.size), np.argmin(dist, axis=1)]  # NaN without one
    return out


def receptive_field_px(net: ResidualFCN, size: int = 256) -> int:
    """Width in pixels of the input region that changes the centre pixel's output (measured:
    the gradient of the centre output with respect to a random input)."""
    gen = torch.Generator().manual_seed(0)
    x = torch.randn(1, N_INPUTS, size, size, generator=gen, requires_grad=True)
    net.raw(x)[0, 0, size // 2, size // 2].backward()
    grad = x.grad.abs().sum(dim=(0, 1))
    cols = torch.nonzero(grad.sum(0) > 0)
    return int(cols.max() - cols.min() + 1) if cols.numel() else 0
