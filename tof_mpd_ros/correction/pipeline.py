"""The full correction (paper Fig. 3): calibration -> F -> G edges -> geodesic filtering.

``correct(model, range_mm, amplitude)`` runs, per frame:

1. the per-pixel intrinsic calibration, giving R (NaN where the measurement is invalid);
2. one patch encoding of every pixel (im2col of the NaN-padded frame, column layout), shared by
   both networks: :class:`~.networks.FusedPatchNets` runs F's and the four G heads' first layers
   as two GEMMs (a stacked 200 x 121 weight against the x_R and x_A rows), F's one-hot terms as
   lookups, then the small layers (G's as batched GEMMs), all channels-first without copies;
3. R_F = R + F(p);
4. G's four edge probabilities -> ``edges.edge_map_from_responses`` (max over orientations,
   non-maximum suppression, hysteresis) -> binary edge map;
5. ``geodesic.geodesic_filter`` of R_F over the K = 81 geodesic neighbours (sigma = 2).

Either network can be switched off for the paper's component analysis. Invalid pixels (NaN, inf,
range or amplitude <= 0) are NaN in every range output and 0 in ``confidence``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from ..errors import InputError
from ..validation import check_array
from .calibration import IntrinsicCalibration
from .encoding import ColumnEncoding, EncodingConfig, encode_frame_columns
from .networks import BoundaryNets, FusedPatchNets, RangeRecoveryNet


@dataclass(frozen=True)
class GeodesicParams:
    """Geodesic filter constants (paper: K = 81 neighbours, sigma = 2, unit grid step)."""

    k: int = 81
    sigma: float = 2.0
    step: float = 1.0

    def __post_init__(self) -> None:
        if not (self.k >= 1 and self.sigma > 0 and self.step > 0):
            raise InputError(f"geodesic parameters must be k >= 1, sigma > 0, step > 0, "
                             f"got {self}")


@dataclass
class CorrectionModel:
    """Everything the correction needs; one weights file holds exactly this.

    Attributes:
        calibration: per-pixel intrinsic calibration; its (H, W) is the model's crop.
        encoding: patch-encoding constants the networks were trained with.
        range_net: F.
        boundary_nets: the four G heads.
        geodesic: geodesic filter constants.
        metadata: provenance (training data digest, code revision, history summary...).
    """

    calibration: IntrinsicCalibration
    encoding: EncodingConfig
    range_net: RangeRecoveryNet
    boundary_nets: BoundaryNets
    geodesic: GeodesicParams = field(default_factory=GeodesicParams)
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.range_net.n_features != self.encoding.n_features:
            raise InputError(f"range net expects {self.range_net.n_features} inputs, the "
                             f"encoding gives {self.encoding.n_features}")
        if self.boundary_nets.n_features != self.encoding.n_boundary_features:
            raise InputError(f"boundary nets expect {self.boundary_nets.n_features} inputs, "
                             f"the encoding gives {self.encoding.n_boundary_features}")

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the frames this model corrects (the crop it was calibrated on)."""
        return self.calibration.shape

    @classmethod
    def untrained(cls, calibration: IntrinsicCalibration,
                  encoding: EncodingConfig | None = None, *, seed: int = 0,
                  geodesic: GeodesicParams | None = None) -> CorrectionModel:
        """A model with freshly initialised networks (seeded), e.g. to start training."""
        enc = encoding or EncodingConfig()
        gen = torch.Generator().manual_seed(seed)
        return cls(calibration, enc, RangeRecoveryNet(enc.n_features, generator=gen),
                   BoundaryNets(enc.n_boundary_features, generator=gen),
                   geodesic or GeodesicParams())

    def to(self, device: torch.device | str) -> CorrectionModel:
        """Move both networks to ``device`` (in place) and return self."""
        self.range_net.to(device)
        self.boundary_nets.to(device)
        return self


@dataclass
class CorrectionResult:
    """Output of :func:`correct`; every array is (H, W) or (B, H, W) like the input.

    Attributes:
        range_mm: float32 final corrected radial range in mm (R-hat), NaN = invalid.
        edges: bool binary boundary map from G (all False when G is skipped).
        confidence: float32 in [0, 1], the probability per G that the pixel is *not* on an
            object boundary, ``1 - max_k P_edge,k(p)``: boundary pixels are where mixed pixels
            and over-smoothing make ToF least reliable. 1 on valid pixels when G is skipped,
            0 on invalid pixels.
        calibrated_mm: float32 range after the intrinsic calibration only (R), NaN = invalid.
        range_f_mm: float32 range after F only (R_F = R + F), NaN = invalid; equals
            ``calibrated_mm`` when F is skipped.
        valid: bool, the pixels with a usable measurement.
    """

    range_mm: np.ndarray
    edges: np.ndarray
    confidence: np.ndarray
    calibrated_mm: np.ndarray
    range_f_mm: np.ndarray
    valid: np.ndarray


def check_frame_pair(model_shape: tuple[int, int], range_mm: object, amplitude: object
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Validate a (H, W) or (B, H, W) range/amplitude pair against the model's crop.

    Raises:
        InputError: wrong dimensions, dtype, mismatched shapes or a crop other than the model's.
    """
    r = check_array("range_mm", range_mm, ndim=(2, 3), dtype_kind="fiu")
    a = check_array("amplitude", amplitude, ndim=(2, 3), dtype_kind="fiu")
    if r.shape != a.shape:
        raise InputError(f"range_mm {r.shape} and amplitude {a.shape} differ in shape")
    if r.shape[-2:] != tuple(model_shape):
        h, w = model_shape
        raise InputError(f"frame is {r.shape[-1]}x{r.shape[-2]} (W x H) but the model was "
                         f"calibrated and trained on a {w}x{h} crop; crop the frame first")
    return r, a


def correct(
    model: CorrectionModel,
    range_mm: np.ndarray,
    amplitude: np.ndarray,
    *,
    device: torch.device | str = "cpu",
    use_range_net: bool = True,
    use_boundary: bool = True,
    precision: str = "float32",
) -> CorrectionResult:
    """Remove multipath distortion from one frame or a batch of frames.

    Args:
        model: the correction model; its networks are moved to ``device``.
        range_mm: (H, W) or (B, H, W) float raw radial range in mm; NaN/inf/<= 0 = invalid.
        amplitude: same shape, raw amplitude in sensor units; NaN/inf/<= 0 = invalid.
        device: torch device for the networks (CPU default; GPU optional).
        use_range_net: apply F (off: R_F = R, "geodesic filtering alone").
        use_boundary: apply G + geodesic filtering (off: R-hat = R_F, "F alone").
        precision: ``"float32"`` or ``"bfloat16"`` for the networks' first-layer GEMMs (see
            :class:`~tof_mpd_ros.correction.networks.FusedPatchNets`).

    Returns:
        A :class:`CorrectionResult` shaped like the input.

    Raises:
        InputError: see :func:`check_frame_pair`; an unknown ``precision``.
    """
    r, a = check_frame_pair(model.shape, range_mm, amplitude)
    single = r.ndim == 2
    r3 = r[None] if single else r
    a3 = (a[None] if single else a).astype(np.float32, copy=False)
    calibrated = model.calibration.apply(r3, a3)
    dev = torch.device(device)
    model.to(dev)
    fused = FusedPatchNets(model.range_net, model.boundary_nets, model.encoding.patch_size,
                           model.encoding.n_bins, precision)
    encodings = encode_frame_columns(calibrated, a3, model.encoding, device=dev)
    parts = [_correct_one(model, fused, enc, calibrated[i], use_range_net, use_boundary)
             for i, enc in enumerate(encodings)]
    fields = [np.stack(x) for x in zip(*parts, strict=True)]
    result = CorrectionResult(*fields)
    if single:
        result = CorrectionResult(*(x[0] for x in fields))
    return result


def _correct_one(model: CorrectionModel, fused: FusedPatchNets, enc: ColumnEncoding,
                 calibrated: np.ndarray, use_f: bool, use_g: bool
                 ) -> tuple[np.ndarray, ...]:
    """One frame: (range, edges, confidence, calibrated, range_f, valid), each (H, W)."""
    h, w = calibrated.shape
    nan = np.float32(np.nan)
    valid = enc.valid.cpu().numpy()
    calib = np.where(valid, calibrated, nan).astype(np.float32)
    if not (use_f or use_g):
        return calib, np.zeros((h, w), bool), valid.astype(np.float32), calib, calib, valid
    correction, probs = fused(enc.x_range, enc.x_amplitude, enc.bin_range, enc.bin_amplitude)
    range_f = calib
    if use_f:
        range_f = (calib + correction.cpu().numpy().reshape(h, w)).astype(np.float32)
    if not use_g:
        return (range_f, np.zeros((h, w), bool), valid.astype(np.float32), calib, range_f,
                valid)
    scores = probs.reshape(-1, h, w).cpu().numpy()                       # (4, H, W)
    scores = np.where(valid, scores, np.float32(0.0)).astype(np.float32)
    confidence = np.where(valid, 1.0 - scores.max(axis=0), 0.0).astype(np.float32)
    edges, filtered = _filter_one(model.geodesic, range_f, scores)
    final = np.where(valid, filtered, nan).astype(np.float32)
    return final, edges, confidence, calib, range_f, valid


def _filter_one(params: GeodesicParams, range_f: np.ndarray, probs: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Edge map from the four G responses, then the geodesic filter of R_F over it."""
    # Imported here: edges/geodesic are separate modules that pull in OpenCV/scipy.
    from . import edges as edge_module
    from . import geodesic

    edge_map, _strength = edge_module.edge_map_from_responses(probs)
    filtered = geodesic.geodesic_filter(range_f, edge_map, k=params.k, sigma=params.sigma,
                                        step=params.step)
    return np.asarray(edge_map, bool), np.asarray(filtered, np.float32)
