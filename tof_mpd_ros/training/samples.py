"""Training samples: calibrated frames, per-pixel targets and labels, patches gathered on demand.

Memory stays bounded at MD scale (540 frames of 180 x 140, ~10 M usable pixels, the paper's
"10 million patches"): the 280-wide encodings (~11 GB for 10 M) are never stored. What is kept is
the NaN-padded calibrated range and log-amplitude planes of every frame (~0.2 GB) and int64 pixel
indices; a batch's pixels are encoded from those planes by the same kernels as inference
(:mod:`tof_mpd_ros.correction.encoding`), so training and inference see bit-identical features.

Per usable pixel (valid ToF measurement after calibration *and* a reference, i.e. not missing):

* F target ``t = clip(R* - R, -T, T)`` in mm (T = 15 mm; R is the *calibrated* range);
* G label: the orientation group 0..3 of :func:`edges.ground_truth_edges` on the reference, or -1
  for non-edge pixels. Head k's positives are group k; everything else is its negative.

Pixel sampling (:func:`sample_pixels`): per frame, uniformly without replacement among usable
pixels, at most ``max_per_frame`` (None = all of them, the paper's setting), drawn from a seeded
``torch.Generator``.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from scipy.ndimage import binary_dilation

from ..calibration.intrinsic import IntrinsicCalibration
from ..correction.encoding import EncodingConfig, encode_pixels, padded_planes
from ..errors import InputError
from ..frame import ToFFrame

#: the paper's truncation of the F target, mm (the floor of the data-driven one)
PAPER_TARGET_CLIP_MM = 15.0
#: the data-driven truncation covers this quantile of the training set's |distortion|
TARGET_CLIP_QUANTILE = 0.99
#: ...over the pixels more than this many pixels from a ground-truth depth edge
EDGE_MARGIN_PX = 2


@dataclass
class TrainingData:
    """Frames prepared for patch sampling (all tensors on CPU).

    Attributes:
        range_planes: (N, H + P - 1, W + P - 1) float32 calibrated range in mm, NaN-padded,
            NaN where invalid.
        log_amp_planes: same shape, natural-log amplitude.
        amplitude: (N, H, W) float32 amplitude (for b_A).
        target: (N, H, W) float32 truncated correction t = clip(R* - R, -T, T) in mm, NaN where
            the pixel is not usable.
        group: (N, H, W) int8 ground-truth edge orientation group 0..3, -1 = non-edge.
        usable: (N, H, W) bool, valid measurement and reference present.
        calibrated: (N, H, W) float32 calibrated range R in mm (NaN = invalid).
        reference: (N, H, W) float32 reference range R* in mm (NaN = missing).
        encoding: the encoding constants.
        digest: SHA-256 of the raw frames and the calibration (provenance, checkpoint check).
        target_clip_mm: T, the truncation applied to ``target``, mm.
    """

    range_planes: torch.Tensor
    log_amp_planes: torch.Tensor
    amplitude: torch.Tensor
    target: torch.Tensor
    group: torch.Tensor
    usable: torch.Tensor
    calibrated: torch.Tensor
    reference: torch.Tensor
    encoding: EncodingConfig
    digest: str
    target_clip_mm: float = PAPER_TARGET_CLIP_MM

    @property
    def n_frames(self) -> int:
        return int(self.usable.shape[0])

    @property
    def frame_shape(self) -> tuple[int, int]:
        return int(self.usable.shape[1]), int(self.usable.shape[2])

    def gather(self, flat_index: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Encode the pixels ``flat_index`` (into the (N, H, W) grid).

        Args:
            flat_index: (M,) int64 flat pixel indices.

        Returns:
            ``(features, target, group)``: (M, 280) float32, (M,) float32 mm, (M,) int64.
        """
        feats = torch.from_numpy(encode_pixels(
            self.range_planes.numpy(), self.log_amp_planes.numpy(), self.amplitude.numpy(),
            flat_index.numpy(), self.encoding))
        return (feats, self.target.reshape(-1)[flat_index],
                self.group.reshape(-1)[flat_index].long())


def frames_digest(frames: Sequence[ToFFrame], calibration: IntrinsicCalibration) -> str:
    """SHA-256 over every frame's range, amplitude and reference and the calibration."""
    h = hashlib.sha256()
    for f in frames:
        for a in (f.range_mm, f.amplitude, f.reference_mm):
            h.update(np.ascontiguousarray(a, np.float32).tobytes())
    for name, a in sorted(calibration.to_arrays().items()):
        h.update(name.encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def check_training_frames(frames: Sequence[ToFFrame], shape: tuple[int, int]) -> None:
    """Raise :class:`InputError` unless every frame has a reference and the given (H, W)."""
    if len(frames) == 0:
        raise InputError("training needs at least one frame, got none")
    for i, f in enumerate(frames):
        if f.reference_mm is None:
            raise InputError(f"frame {i} has no reference_mm; training frames need the "
                             "structured-light reference")
        if f.range_mm.shape != tuple(shape):
            raise InputError(f"frame {i} is {f.range_mm.shape} (H, W) but the calibration is "
                             f"{tuple(shape)}; crop the frames to the calibration's crop")


def distortion_clip_mm(calibrated: np.ndarray, reference: np.ndarray, *,
                       quantile: float = TARGET_CLIP_QUANTILE,
                       floor_mm: float = PAPER_TARGET_CLIP_MM) -> float:
    """The F target's truncation T from the data: the ``quantile`` of |R* − R| over the pixels
    with both values, never below ``floor_mm`` (the paper's 15 mm), rounded up to a whole mm.

    The paper truncates at 15 mm, which its DS325 data rarely exceeded away from edges; a
    path-traced or bright scene puts 10 % of the interior pixels beyond it (box faces +30 mm),
    and a truncated target cannot correct them. Flying pixels and outliers past the quantile
    stay truncated.

    Args:
        calibrated: (N, H, W) float calibrated ToF range, mm.
        reference: (N, H, W) float reference range, mm (NaN = missing).
    """
    with np.errstate(invalid="ignore"):
        d = np.abs(np.asarray(reference, np.float64) - np.asarray(calibrated, np.float64))
    d = d[np.isfinite(d)]
    if d.size == 0:
        return float(floor_mm)
    return float(max(floor_mm, math.ceil(float(np.quantile(d, quantile)))))


def interior_clip_mm(calibrated: np.ndarray, reference: np.ndarray, usable: np.ndarray,
                     edge_pixels: np.ndarray) -> float:
    """:func:`distortion_clip_mm` over the usable pixels more than ``EDGE_MARGIN_PX`` from a
    ground-truth edge: mixed pixels on the edges are off by the depth step itself (hundreds of
    mm), which is G's and the geodesic step's business, not F's.

    Args:
        calibrated, reference: (N, H, W) float ranges, mm.
        usable: (N, H, W) bool pixels with a measurement and a reference.
        edge_pixels: (N, H, W) bool ground-truth edges.
    """
    near = np.stack([binary_dilation(e, iterations=EDGE_MARGIN_PX) for e in edge_pixels])
    interior = usable & ~near
    return distortion_clip_mm(calibrated[interior], reference[interior])


def prepare_training_data(frames: Sequence[ToFFrame], calibration: IntrinsicCalibration,
                          encoding: EncodingConfig, *,
                          target_clip_mm: float | None = PAPER_TARGET_CLIP_MM
                          ) -> TrainingData:
    """Calibrate the frames, compute targets and ground-truth edge labels.

    Args:
        frames: ToF frames with ``reference_mm`` (NaN = missing), all of the calibration's (H, W).
        calibration: applied to every frame first (as at inference).
        encoding: patch encoding constants.
        target_clip_mm: T, the truncation of the F target; None = from the data
            (:func:`distortion_clip_mm` over the usable pixels more than ``EDGE_MARGIN_PX``
            from a ground-truth edge), stored in ``TrainingData.target_clip_mm`` either way.

    Returns:
        The prepared :class:`TrainingData`.

    Raises:
        InputError: no frames, a frame without reference, or a frame of another size.
    """
    from ..correction import edges  # OpenCV-based; imported where it is needed

    check_training_frames(frames, calibration.shape)
    rng_ = np.stack([f.range_mm for f in frames])
    amp = np.stack([f.amplitude for f in frames]).astype(np.float32)
    ref = np.stack([f.reference_mm for f in frames]).astype(np.float32)
    calibrated = calibration.apply(rng_, amp)
    planes = padded_planes(calibrated, amp, encoding)
    usable = torch.from_numpy(planes.valid) & torch.from_numpy(np.isfinite(ref))
    gt = [edges.ground_truth_edges(r) for r in ref]
    if target_clip_mm is None:
        target_clip_mm = interior_clip_mm(calibrated, ref, usable.numpy(),
                                          np.stack([e for e, _ in gt]))
    with np.errstate(invalid="ignore"):
        t = np.clip(ref - calibrated, -target_clip_mm, target_clip_mm)
    target = torch.where(usable, torch.from_numpy(t.astype(np.float32)), float("nan"))
    group = torch.from_numpy(np.stack([g for _, g in gt]))
    group = torch.where(usable, group.to(torch.int8), torch.tensor(-1, dtype=torch.int8))
    return TrainingData(
        range_planes=torch.from_numpy(planes.range_mm),
        log_amp_planes=torch.from_numpy(planes.log_amplitude),
        amplitude=torch.from_numpy(amp), target=target, group=group, usable=usable,
        calibrated=torch.from_numpy(calibrated), reference=torch.from_numpy(ref),
        encoding=encoding, digest=frames_digest(frames, calibration),
        target_clip_mm=float(target_clip_mm))


def sample_pixels(data: TrainingData, frame_ids: Sequence[int], max_per_frame: int | None,
                  generator: torch.Generator) -> torch.Tensor:
    """Usable pixels of the given frames, at most ``max_per_frame`` each, shuffled.

    Args:
        data: prepared frames.
        frame_ids: which frames to draw from.
        max_per_frame: cap per frame (uniform without replacement), None = all usable pixels.
        generator: the source of randomness (same generator state -> same samples).

    Returns:
        (M,) int64 flat indices into (N, H, W), in random order.
    """
    h, w = data.frame_shape
    chosen = []
    for i in frame_ids:
        idx = torch.nonzero(data.usable[i].reshape(-1)).reshape(-1)
        if max_per_frame is not None and idx.numel() > max_per_frame:
            idx = idx[torch.randperm(idx.numel(), generator=generator)[:max_per_frame]]
        chosen.append(idx + int(i) * h * w)
    if not chosen:
        return torch.zeros(0, dtype=torch.int64)
    flat = torch.cat(chosen)
    return flat[torch.randperm(flat.numel(), generator=generator)]


def auto_encoding(data_frames: Sequence[ToFFrame], calibration: IntrinsicCalibration,
                  base: EncodingConfig, *, quantile: float = 0.005) -> EncodingConfig:
    """``base`` with the b_R / b_A intervals set to the [q, 1 - q] quantiles of the data.

    Makes the one-hot bins span the ranges and amplitudes actually seen (amplitude has no
    universal unit), so no bin is wasted on values that never occur.
    """
    from dataclasses import replace

    amp = np.stack([f.amplitude for f in data_frames])
    cal = calibration.apply(np.stack([f.range_mm for f in data_frames]), amp)
    ok = np.isfinite(cal) & (cal > 0)
    if not ok.any():
        raise InputError("no valid pixel in the training frames")
    r_lo, r_hi = np.quantile(cal[ok], [quantile, 1 - quantile])
    a_lo, a_hi = np.quantile(amp[ok], [quantile, 1 - quantile])
    # Guard against constant data, which would give an empty interval.
    return replace(base, range_min_mm=float(r_lo), range_max_mm=float(max(r_hi, r_lo + 1.0)),
                   amplitude_min=float(a_lo),
                   amplitude_max=float(max(a_hi, a_lo + 1e-6 * max(abs(a_lo), 1.0))))
