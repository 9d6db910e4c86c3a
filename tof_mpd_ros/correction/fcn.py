"""The second model kind: a fully-convolutional residual network with per-pixel uncertainty.

Why a U-Net. F and G see an 11×11 patch, about 15 mm at 300 mm, but with faithful light
transport a box's side face is lit from table 100+ mm away. A U-Net reaches far at little cost:
each level halves the resolution, so five levels of two 3×3 convolutions see about 140 px
(measured by :func:`receptive_field_px`) while most of the arithmetic stays at the coarse
levels; the skip connections carry the full-resolution detail back to every pixel. A
kernel-predicting network would have to predict kernels that large, and a plain dilated stack
aliases on the ToF's 1-px structures (flying pixels).

Why a residual, not a filter. The output is ``R + Δ(p)``: every pixel's own calibrated range
plus a predicted correction, never a weighted mean of its neighbours, so nothing is blurred
across a depth edge by construction. A flying pixel (a mix of both sides) gets a correction
towards one side where the network is sure of the side, and a large predicted σ where it is
not, and is then invalidated (``max_sigma_mm``).

Why σ. The network predicts the correction's mean and standard deviation, trained with the
Gaussian negative log-likelihood (a proper scoring rule: the expected loss is lowest at the true
σ), so σ means millimetres of expected error and can be checked: the fraction of pixels with
``|error| <= k σ`` should be 68 / 95 / 99.7 % for k = 1, 2, 3.

Inputs, per pixel (0 where the measurement is invalid; the frame is zero-padded to a multiple
of ``2^(levels - 1)``): the calibrated range relative to the frame's median (per 100 mm), the
absolute range (m: multipath depends on scale), the log amplitude relative to the frame's
median, and the validity mask.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as tnf

from ..calibration.intrinsic import IntrinsicCalibration, valid_measurement
from ..errors import InputError

#: input channels of :func:`fcn_inputs`
N_INPUTS = 4
#: range units of the relative-range channel, mm
RANGE_SCALE_MM = 100.0


@dataclass(frozen=True)
class FCNArchitecture:
    """Shape of :class:`ResidualFCN` and its output scaling, stored in the weights file.

    Attributes:
        widths: channels per level, finest first; ``len(widths)`` levels, each but the last
            followed by a stride-2 downsampling.
        correction_scale_mm: the correction output unit, mm (keeps the last layer well scaled).
        sigma_floor_mm: smallest σ the network can predict, mm (no pixel is certain to 0 mm).
        sigma_scale_mm: σ = floor + scale · softplus(output), mm.
    """

    widths: tuple[int, ...] = (8, 16, 32, 48, 64)
    correction_scale_mm: float = 10.0
    sigma_floor_mm: float = 0.3
    sigma_scale_mm: float = 5.0

    def __post_init__(self) -> None:
        if len(self.widths) < 2 or any(int(w) < 1 for w in self.widths):
            raise InputError(f"FCN widths need >= 2 levels of >= 1 channel, got {self.widths}")
        if not (self.correction_scale_mm > 0 and self.sigma_floor_mm > 0
                and self.sigma_scale_mm > 0):
            raise InputError(f"FCN output scales must be > 0: {self}")
        object.__setattr__(self, "widths", tuple(int(w) for w in self.widths))

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
    """U-Net: inputs (B, 4, H, W) -> (correction mm, σ mm), each (B, H, W).

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
        self.head = nn.Conv2d(w[0], 2, 1)
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
        """(B, 2, H, W) unscaled outputs of ``x`` (B, 4, H, W)."""
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
        return self.head(x)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(correction mm, σ mm), each (B, H, W) float32."""
        return self.scale(self.raw(x))

    def scale(self, out: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(correction mm, σ mm) of the raw outputs (B, 2, H, W)."""
        a = self.architecture
        sigma = a.sigma_floor_mm + a.sigma_scale_mm * tnf.softplus(out[:, 1])
        return a.correction_scale_mm * out[:, 0], sigma


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
        ``(x, valid)``: x (B, 4, H', W') float32 (zero-padded at the bottom and right), valid
        (B, H, W) bool.
    """
    r = np.asarray(calibrated_mm, np.float32)
    a = np.asarray(amplitude, np.float32)
    valid = valid_measurement(r, a)
    with np.errstate(invalid="ignore", divide="ignore"):
        log_a = np.where(valid, np.log(np.where(valid, a, 1.0)), 0.0).astype(np.float32)
        r0 = np.where(valid, r, 0.0).astype(np.float32)
    rel = (r0 - _median_per_frame(r0, valid)) / RANGE_SCALE_MM
    planes = np.stack([np.where(valid, rel, 0.0), r0 / 1000.0,
                       np.where(valid, log_a - _median_per_frame(log_a, valid), 0.0),
                       valid.astype(np.float32)], axis=1).astype(np.float32)
    h, w = r.shape[-2:]
    hp, wp = -(-h // multiple) * multiple, -(-w // multiple) * multiple
    x = torch.from_numpy(planes)
    if (hp, wp) != (h, w):
        x = tnf.pad(x, (0, wp - w, 0, hp - h))
    return x, valid


def gaussian_nll(correction_mm: torch.Tensor, sigma_mm: torch.Tensor, target_mm: torch.Tensor,
                 mask: torch.Tensor) -> torch.Tensor:
    """Mean Gaussian negative log-likelihood (nats per pixel) of ``target`` over ``mask``:
    ``0.5 ((t - μ) / σ)² + log σ + 0.5 log 2π``; every tensor (B, H, W)."""
    t = torch.where(mask, target_mm, torch.zeros_like(target_mm))
    z = (t - correction_mm) / sigma_mm
    nll = 0.5 * z.square() + torch.log(sigma_mm) + 0.5 * math.log(2 * math.pi)
    n = mask.sum().clamp(min=1)
    return torch.where(mask, nll, torch.zeros_like(nll)).sum() / n


@dataclass
class FCNCorrectionModel:
    """Calibration + :class:`ResidualFCN`: the ``"fcn"`` kind of correction model.

    Attributes:
        calibration: per-pixel intrinsic calibration of the crop.
        net: the network.
        max_sigma_mm: pixels whose predicted σ exceeds this are invalid in the output (NaN).
        metadata: provenance (training data digest, config, history summary...).
    """

    calibration: IntrinsicCalibration
    net: ResidualFCN
    max_sigma_mm: float = 10.0
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
                  max_sigma_mm: float = 10.0) -> FCNCorrectionModel:
        """A model with a freshly initialised (seeded) network."""
        net = ResidualFCN(architecture, generator=torch.Generator().manual_seed(seed))
        return cls(calibration, net, max_sigma_mm)

    def to(self, device: torch.device | str) -> FCNCorrectionModel:
        self.net.to(device)
        return self


@torch.inference_mode()
def run_fcn(net: ResidualFCN, calibrated_mm: np.ndarray, amplitude: np.ndarray, *,
            device: torch.device | str = "cpu", precision: str = "float32"
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Correction and σ of a batch of frames.

    Args:
        net: the network (put in eval mode).
        calibrated_mm: (B, H, W) float32 calibrated range, mm, NaN = invalid.
        amplitude: (B, H, W) float32 amplitude.
        device: where the network runs (it is moved there).
        precision: ``"float32"`` or ``"bfloat16"`` (the convolutions under autocast; the
            output scaling and σ stay float32).

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
    # channels-last: oneDNN's direct convolutions run faster on NHWC on the CPU
    x = x.to(dev).contiguous(memory_format=torch.channels_last)
    with torch.autocast(dev.type, dtype=torch.bfloat16, enabled=precision == "bfloat16"):
        out = net.raw(x)
    corr, sigma = net.scale(out.float())
    nan = np.float32(np.nan)
    corr_np = corr[:, :h, :w].float().cpu().numpy()
    sigma_np = sigma[:, :h, :w].float().cpu().numpy()
    return (np.where(valid, corr_np, nan).astype(np.float32),
            np.where(valid, sigma_np, nan).astype(np.float32), valid)


def receptive_field_px(net: ResidualFCN, size: int = 256) -> int:
    """Width in pixels of the input region that changes the centre pixel's output (measured:
    the gradient of the centre output with respect to a random input)."""
    gen = torch.Generator().manual_seed(0)
    x = torch.randn(1, N_INPUTS, size, size, generator=gen, requires_grad=True)
    net.raw(x)[0, 0, size // 2, size // 2].backward()
    grad = x.grad.abs().sum(dim=(0, 1))
    cols = torch.nonzero(grad.sum(0) > 0)
    return int(cols.max() - cols.min() + 1) if cols.numel() else 0
