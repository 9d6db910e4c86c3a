"""The full correction (paper Fig. 3): calibration -> F -> G edges -> geodesic filtering.

``correct(model, range_mm, amplitude)`` runs, per frame:

1. the per-pixel intrinsic calibration, giving R (NaN where the measurement is invalid);
2. one patch encoding of every pixel, shared by both networks (``encoding``);
3. R_F = R + F(p);
4. G's four edge probabilities, reduced to their maximum and its orientation group ->
   ``edges.edge_map_from_best`` (non-maximum suppression, hysteresis) -> binary edge map;
5. ``geodesic.geodesic_filter`` of R_F over the K = 81 geodesic neighbours (sigma = 2).

Either network can be switched off for the paper's component analysis. Invalid pixels (NaN, inf,
range or amplitude <= 0) are NaN in every range output and 0 in ``confidence``.

Steps 2-4 run in an :class:`_Engine` cached per model state, shape, precision and device (issue
8); an engine corrects one frame at a time, and callers correcting frames at once (the
node's ``parallel_frames``) each take a free engine of the model's, built when none is free:

* compiled kernels fill NaN-padded range / log-amplitude planes and the one-hot bins into
  preallocated buffers (``encoding.frame_planes``);
* on the CPU the frame is cut into bands of ~2880 pixels; ``threads`` worker threads (default:
  torch's thread count, capped by the usable CPUs) take bands in turn and, per band, encode the
  pixels feature-major into a cache-resident buffer (``encoding.encode_band``), run one oneDNN
  GEMM for the first layers of F and the four G heads, and compiled kernels and one batched
  GEMM for the rest of both networks (``networks.PatchNets``), which also reduces the four
  heads to the per-pixel maximum and its group. Workers run torch with 1 intra-op thread each
  (set for the call and restored), so the two levels of threading never stack; numba's
  kernels release the GIL. On another torch device the frame is one band, encoded on the CPU
  and run by ``PatchNets``' torch backend on the device;
* NMS + hysteresis (``edges.edge_map_from_best``) and the geodesic filter (serial numba
  kernels on ``numba.get_num_threads()`` Python threads). No OpenMP team runs anywhere in the
  CPU path, so no idle OpenMP thread spins against the working ones whatever wait policy
  libgomp was loaded with.

The result agrees with the straightforward oracle (``test/oracles/reference_pipeline.py``): the
same edges and the corrected range within ~1e-4 mm (float32 summation order only; measured
6.1e-5 mm, one float32 ulp at 256-512 mm). ``precision="bfloat16"`` and ``"int8"`` are opt-in;
they recompute G in float32 at the pixels whose edge decision their rounding could change
(``edges.unsure_edge_decisions``, ``_Engine._recheck_unsure``), so their edges are float32's
but at a few pixels and their final range is within 0.5 mm of float32's on 99.99 % of
MD-Test's pixels (docs/performance.md).
"""

from __future__ import annotations

import contextlib
import functools
import os
import threading
import warnings
import weakref
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch

from ..calibration.intrinsic import IntrinsicCalibration, valid_measurement
from ..errors import CalibrationError, InputError
from ..machine import SlowPrecisionWarning, slow_precision
from ..thread_pools import shared_pool
from ..validation import check_array
from .encoding import (
    EncodingConfig,
    encode_band,
    encode_band_int8,
    encode_pixels,
    frame_planes,
    plane_constants,
)
from .fcn import FCNCorrectionModel, resolve_to_a_side, run_fcn
from .networks import (
    PATCH_PRECISIONS,
    BoundaryNets,
    FrameBins,
    HeadOutputs,
    PatchNets,
    RangeRecoveryNet,
    weights_version,
)

# Pixels per band on the CPU: the band's encodings (240 x 2880, 2.8 MB in float32, 0.7 MB in
# int8) and the GEMM output (200 x 2880) stay in L2/L3 between the encoding, the GEMM and the
# small layers. Measured on a 2-core Xeon (docs/performance.md, session 20): at 320x240, 2880
# beat 1440 by 4-9 % and 5760 by 3-10 %; at 180x140 1440 to 5760 were within the noise.
BAND_PIXELS = 2880
# Reduced precisions: the largest error assumed of one of G's logit differences against
# float32, and of the difference between two such errors (two pixels', or two heads' of one
# pixel), for the pixels rechecked in float32 (``edges.unsure_edge_decisions``). Measured on
# MD-Test (45 frames, shipped weights, docs/performance.md), int8 / bfloat16: one logit at most
# 0.32 / 0.10 (99.99th percentiles 0.20 / 0.055); neighbours along a normal 0.34 / 0.11, a
# pixel's best and runner-up heads 0.38 / 0.11. These are about twice that.
RECHECK_LOGIT_ERROR = {"bfloat16": (0.2, 0.23), "int8": (0.6, 0.75)}
# A frame with more unsure pixels than this share of its valid ones keeps the reduced edges:
# G is undecided nearly everywhere (untrained weights score ~0.5 at every pixel), and checking
# it all would be slower than float32 (docs/performance.md). Trained weights on MD-Test: a
# median of 5.3 % (int8) and 1.7 % (bfloat16), at most 11.3 %.
RECHECK_MAX_SHARE = 0.25
# Pixels per float32 recheck GEMM: a few fixed shapes, so oneDNN builds each kernel once (a new
# pixel count per frame re-created the primitive: ~4 ms per frame); the last chunk takes the
# smallest that holds the rest.
RECHECK_CHUNKS = (256, 512, 1024)
RECHECK_CHUNK = RECHECK_CHUNKS[-1]


@dataclass(frozen=True)
class GeodesicParams:
    """Geodesic filter constants (paper: K = 81 neighbours, sigma = 2, unit grid step) and the
    hysteresis thresholds that turn G's probabilities into the edge map it respects (0.3 /
    0.6 by default; the trainer chooses them on its validation frames)."""

    k: int = 81
    sigma: float = 2.0
    step: float = 1.0
    edge_low: float = 0.3
    edge_high: float = 0.6

    def __post_init__(self) -> None:
        if not (self.k >= 1 and self.sigma > 0 and self.step > 0):
            raise InputError(f"geodesic parameters must be k >= 1, sigma > 0, step > 0, "
                             f"got {self}")
        if not 0.0 <= self.edge_low <= self.edge_high:
            raise InputError(f"edge thresholds must be 0 <= low <= high, got {self}")


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

    kind = "patch"

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
        sigma_mm: float32 predicted standard deviation of the corrected range, mm (the
            ``"fcn"`` kind only; None for the patch networks). There ``confidence`` is
            ``1 - sigma / max_sigma_mm`` clipped to [0, 1], ``edges`` is all False, and a
            pixel with ``sigma > max_sigma_mm`` takes in ``range_mm`` the range of its sure
            neighbour nearest in range, or NaN without one (``range_f_mm`` keeps its own).
    """

    range_mm: np.ndarray
    edges: np.ndarray
    confidence: np.ndarray
    calibrated_mm: np.ndarray
    range_f_mm: np.ndarray
    valid: np.ndarray
    sigma_mm: np.ndarray | None = None


#: the networks' arithmetic :func:`correct` offers (``"int8"``: the patch kind on the CPU)
PRECISIONS = PATCH_PRECISIONS
#: the fcn kind's (its convolutions under autocast)
FCN_PRECISIONS = ("float32", "bfloat16")


@functools.cache
def warn_slow_precision(precision: str) -> str | None:
    """One :class:`SlowPrecisionWarning` per process and precision where this CPU lacks the
    precision's instructions; returns the reason (None: nothing to warn of)."""
    reason = slow_precision(precision)
    if reason is not None:
        warnings.warn(reason, SlowPrecisionWarning, stacklevel=3)
    return reason


def check_precision(model: CorrectionModel | FCNCorrectionModel, precision: str) -> None:
    """Raise InputError unless ``model``'s kind runs in ``precision``."""
    if precision not in PRECISIONS:
        raise InputError(f"precision must be one of {PRECISIONS}, got {precision!r}")
    if isinstance(model, FCNCorrectionModel) and precision not in FCN_PRECISIONS:
        raise InputError(f"precision {precision!r} is the patch kind's; the fcn kind runs in "
                         f"one of {FCN_PRECISIONS}")


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
    model: CorrectionModel | FCNCorrectionModel,
    range_mm: np.ndarray,
    amplitude: np.ndarray,
    *,
    device: torch.device | str = "cpu",
    use_range_net: bool = True,
    use_boundary: bool = True,
    precision: str = "float32",
    threads: int | None = None,
    geodesic: GeodesicParams | None = None,
    fcn_engine: str = "auto",
) -> CorrectionResult:
    """Remove multipath distortion from one frame or a batch of frames.

    Args:
        model: the correction model (either kind); its networks are moved to ``device``. For
            the ``"fcn"`` kind (:class:`~.fcn.FCNCorrectionModel`) the network replaces F, G
            and the geodesic filter: ``use_range_net=False`` gives the calibrated range,
            ``precision`` sets its convolutions' and ``fcn_engine`` their executor
            (:func:`~.fcn.run_fcn`), ``use_boundary``, ``threads`` and ``geodesic`` do not
            apply.
        range_mm: (H, W) or (B, H, W) float raw radial range in mm; NaN/inf/<= 0 = invalid.
        amplitude: same shape, raw amplitude in sensor units; NaN/inf/<= 0 = invalid.
        device: torch device for the networks (CPU default; GPU optional).
        use_range_net: apply F (off: R_F = R, "geodesic filtering alone").
        use_boundary: apply G + geodesic filtering (off: R-hat = R_F, "F alone").
        precision: ``"float32"`` (default: matches the reference within 1e-3 mm),
            ``"bfloat16"`` (opt-in, faster first-layer GEMMs on AVX512-BF16/AMX CPUs, F off by
            a few hundredths of a mm) or ``"int8"`` (opt-in, the patch kind on the CPU: int8
            first-layer GEMM on AVX512-VNNI/AMX-INT8; see :class:`~.networks.PatchNets`). On
            a CPU without those instructions a reduced precision is right but 6-24x slower
            than float32: one :class:`SlowPrecisionWarning` per process says so.
        threads: worker threads on the CPU (default: torch's thread count, capped by the
            usable CPUs).
        geodesic: edge thresholds and geodesic filter constants to use instead of
            ``model.geodesic`` (None: the model's, i.e. the weights file's).
        fcn_engine: the fcn kind's executor, one of :data:`~.fcn.FCN_ENGINES` (default
            ``"auto"``: ONNX Runtime on the CPU in float32 on 2+ threads when installed, else
            torch, :func:`~.fcn.fcn_engine`; the two agree within 1e-5 mm).

    Returns:
        A :class:`CorrectionResult` shaped like the input.

    Raises:
        InputError: see :func:`check_frame_pair`; an unknown ``precision`` (or ``"int8"`` for
            the fcn kind, or off the CPU); ``threads`` < 1; an unknown ``fcn_engine``, or
            ``"onnxruntime"`` where it cannot run (:func:`~.fcn.fcn_engine`).
    """
    r, a = check_frame_pair(model.shape, range_mm, amplitude)
    check_precision(model, precision)
    if torch.device(device).type == "cpu":
        warn_slow_precision(precision)
    if isinstance(model, FCNCorrectionModel):
        return _correct_fcn(model, r, a, device, use_range_net, precision, fcn_engine)
    params = model.geodesic if geodesic is None else geodesic
    single = r.ndim == 2
    r3 = r[None] if single else r
    a3 = (a[None] if single else a).astype(np.float32, copy=False)
    calibrated = model.calibration.apply(r3, a3)
    dev = torch.device(device)
    if any(p.device != dev for p in (*model.range_net.parameters(),
                                     *model.boundary_nets.parameters())):
        model.to(dev)
    with _engine(model, precision, _worker_count(threads), dev) as engine:
        parts = [engine.correct(calibrated[i], a3[i], use_range_net, use_boundary, params)
                 for i in range(r3.shape[0])]
    fields = [np.stack(x) for x in zip(*parts, strict=True)]
    result = CorrectionResult(*fields)
    if single:
        result = CorrectionResult(*(x[0] for x in fields))
    return result


def processed_window(model_shape: tuple[int, int], frame_shape: tuple[int, int],
                     crop: tuple[int, int] | None = None) -> tuple[int, int]:
    """(height, width) of the central window of a frame of ``frame_shape`` (H, W) that a model
    of ``model_shape`` (H, W) corrects: ``crop`` (width, height) if given, else the model's
    frame, and never more than the frame. The one rule of the node, ``tof-mpd correct``,
    ``evaluate`` and ``benchmark``: a larger frame is cropped to it, a smaller one is corrected
    whole on the model's central window (:func:`central_window`)."""
    width, height = crop if crop is not None else (model_shape[1], model_shape[0])
    return min(height, frame_shape[0]), min(width, frame_shape[1])


def central_window(model: CorrectionModel | FCNCorrectionModel, width: int, height: int
                   ) -> CorrectionModel | FCNCorrectionModel:
    """The same model (either kind) on the central ``width`` x ``height`` window of its pixels:
    its calibration cut to that window (:meth:`.IntrinsicCalibration.central`), the networks
    shared. A full-sensor model corrects the paper's 180x140 crop this way.

    Raises:
        InputError: the window does not fit in the model's frame.
    """
    if (height, width) == model.shape:
        return model
    try:
        calibration = model.calibration.central(width, height)
    except CalibrationError as err:
        raise InputError(str(err)) from err
    return replace(model, calibration=calibration,
                   metadata={**model.metadata, "central_window": [width, height]})


def require_patch_kind(model: object, what: str) -> None:
    """Refuse ``model`` unless it is of the patch kind (:class:`CorrectionModel`).

    For the operations that exist only for F, G and the geodesic filter (G's edge
    probabilities, the edge threshold choice, the geodesic constants...).

    Args:
        model: a correction model of either kind.
        what: the operation, for the message (e.g. ``"choosing G's edge thresholds"``).

    Raises:
        InputError: ``model`` is of another kind, saying which and why.
    """
    kind = getattr(model, "kind", None)
    if kind != CorrectionModel.kind:
        raise InputError(f"{what} needs a model of the patch kind (F, G and the geodesic "
                         f"filter); this model is of kind {kind!r}, which has no edge map, "
                         "no G and no geodesic filter")


def _correct_fcn(model: FCNCorrectionModel, r: np.ndarray, a: np.ndarray,
                 device: torch.device | str, use_net: bool, precision: str,
                 engine: str = "auto") -> CorrectionResult:
    """:func:`correct` for the ``"fcn"`` kind (see :class:`CorrectionResult`)."""
    single = r.ndim == 2
    r3, a3 = (r[None], a[None]) if single else (r, a)
    a3 = a3.astype(np.float32, copy=False)
    calibrated = model.calibration.apply(r3, a3)
    nan = np.float32(np.nan)
    if use_net:
        corr, sigma, valid = run_fcn(model.net, calibrated, a3, device=device,
                                     precision=precision, engine=engine)
        range_f = (calibrated + corr).astype(np.float32)
        sure = valid & (sigma <= model.max_sigma_mm)
        final = resolve_to_a_side(range_f, sure, valid & ~sure)
        confidence = np.where(valid, np.clip(1 - sigma / model.max_sigma_mm, 0, 1), 0)
    else:
        valid = valid_measurement(calibrated, a3)
        range_f = final = np.where(valid, calibrated, nan).astype(np.float32)
        sigma = np.full(calibrated.shape, nan, np.float32)
        confidence = valid
    calib = np.where(valid, calibrated, nan).astype(np.float32)
    fields = (final, np.zeros(valid.shape, bool), confidence.astype(np.float32), calib,
              range_f, valid, sigma)
    return CorrectionResult(*(x[0] for x in fields) if single else fields)


def _worker_count(threads: int | None) -> int:
    """CPU workers: ``threads``, or torch's thread count capped by the usable CPUs."""
    if threads is not None:
        if int(threads) < 1:
            raise InputError(f"threads must be >= 1, got {threads}")
        return int(threads)
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, min(torch.get_num_threads(), usable or 1))


_ENGINES_LOCK = threading.Lock()
# id(model) -> (weak reference to the model, cache key, its engines).
_ENGINES: dict[int, tuple[weakref.ref, tuple, list[_Engine]]] = {}


def _model_key(model: CorrectionModel, precision: str, workers: int,
               device: torch.device) -> tuple:
    """What the engine depends on: network tensors (identity and in-place version), shape..."""
    return (model.shape, model.encoding, precision, workers, str(device),
            float(model.range_net.target_clip_mm),
            weights_version(model.range_net, model.boundary_nets))


@contextlib.contextmanager
def _engine(model: CorrectionModel, precision: str, workers: int,
            device: torch.device) -> Iterator[_Engine]:
    """A free cached engine of ``model``, held for the ``with`` block.

    Engines are rebuilt when the weights change in place. Two frames corrected at once (two
    threads) get two engines, so they run side by side instead of queueing on one engine's
    buffers; a model keeps as many engines as it was ever asked for at once.
    """
    key = _model_key(model, precision, workers, device)
    mid = id(model)
    with _ENGINES_LOCK:
        entry = _ENGINES.get(mid)
        if entry is None or entry[0]() is not model or entry[1] != key:
            entry = (weakref.ref(model, lambda _ref: _ENGINES.pop(mid, None)), key, [])
            _ENGINES[mid] = entry
        engine = next((e for e in entry[2] if not e.busy), None)
        if engine is not None:
            engine.busy = True
    if engine is None:          # built outside the lock: other models' callers need not wait
        engine = _Engine(model, precision, workers, device)
        engine.busy = True
        with _ENGINES_LOCK:
            if _ENGINES.get(mid) is entry:
                entry[2].append(engine)
    try:
        yield engine
    finally:
        with _ENGINES_LOCK:
            engine.busy = False


class _Engine:
    """Fused weights and every buffer of the correction for one model state, shape and device.

    Nothing is allocated per frame but the returned arrays (and the GEMM's band output, which
    the allocator recycles). One frame at a time: :func:`_engine` hands a free engine to each
    caller, and a lock serialises callers that share one directly.

    Args:
        model: the model (its networks are read, not kept).
        precision: one of :data:`PRECISIONS`.
        workers: worker threads on the CPU (1 on other devices).
        device: where the networks run.
        backend: :class:`~.networks.PatchNets`' backend (None: the device's own).
    """

    def __init__(self, model: CorrectionModel, precision: str, workers: int,
                 device: torch.device, backend: str | None = None) -> None:
        h, w = model.shape
        enc = model.encoding
        self.shape = (h, w)
        self.patch_size = enc.patch_size
        self.n_bins = enc.n_bins
        self.nets = PatchNets(model.range_net, model.boundary_nets, enc.patch_size,
                              enc.n_bins, precision, device=device, backend=backend)
        # a reduced precision rechecks G in float32 where an edge decision is unsure
        self.float32_nets = None if precision == "float32" else PatchNets(
            model.range_net, model.boundary_nets, enc.patch_size, enc.n_bins, "float32",
            device=device, backend=backend)
        self.recheck_error = RECHECK_LOGIT_ERROR.get(precision, (0.0, 0.0))
        self.encoding = enc
        self.rechecked = 0          # pixels rechecked in float32 in the last frame
        self.recheck_skipped = 0    # frames whose recheck RECHECK_MAX_SHARE skipped
        self.consts = plane_constants(enc)
        half = enc.patch_size // 2
        self.r_pad = np.full((h + 2 * half, w + 2 * half), np.nan, np.float32)
        self.la_pad = np.full_like(self.r_pad, np.nan)
        self.valid = np.zeros((h, w), bool)
        self.frame = FrameBins(np.zeros(h * w, np.int32), np.zeros(h * w, np.int32),
                               self.valid.reshape(-1))
        self.out = HeadOutputs.zeros(h * w)
        # A device takes the frame as one band (one transfer, one launch per layer).
        rows = max(1, BAND_PIXELS // w) if device.type == "cpu" else h
        self.bands = [(y0, min(h, y0 + rows)) for y0 in range(0, h, rows)]
        self.workers = max(1, min(workers if device.type == "cpu" else 1, len(self.bands)))
        if self.float32_nets is not None:     # one chunk's buffers for the recheck
            self.recheck_x = np.zeros((RECHECK_CHUNK, enc.n_boundary_features), np.float32)
            self.recheck_out = HeadOutputs.zeros(RECHECK_CHUNK)
            self.recheck_scratch = self.float32_nets.scratch(RECHECK_CHUNK)
            # F is not run on rechecked pixels, so their bins are never read
            self.recheck_frame = FrameBins(np.zeros(RECHECK_CHUNK, np.int32),
                                           np.zeros(RECHECK_CHUNK, np.int32),
                                           np.ones(RECHECK_CHUNK, bool))
        band_dtype = torch.int8 if precision == "int8" else torch.float32
        # flat: a band of n pixels is its first n_inputs * n values, (n_inputs, n) contiguous
        self.x = [torch.empty(rows * w * self.nets.n_inputs, dtype=band_dtype)
                  for _ in range(self.workers)]
        self.scratch = [self.nets.scratch(rows * w) for _ in range(self.workers)]
        self.lock = threading.Lock()
        self.busy = False           # held by a caller of _engine (under _ENGINES_LOCK)

    def _work(self, t: int, do_f: bool, do_g: bool) -> None:
        """Worker ``t``: bands t, t + workers, ... (encode, GEMM, small layers)."""
        w = self.shape[1]
        k = self.nets.n_inputs
        for y0, y1 in self.bands[t::self.workers]:
            n = (y1 - y0) * w
            x = self.x[t][:k * n].view(k, n)
            encode = encode_band_int8 if x.dtype == torch.int8 else encode_band
            encode(self.r_pad, self.la_pad, y0, y1, self.patch_size, self.consts, x.numpy())
            first = self.nets.first_layer(x)
            self.nets.heads(first, n, y0 * w, self.frame, do_f, do_g, self.out,
                            self.scratch[t])

    def networks(self, do_f: bool, do_g: bool) -> None:
        """F and G over the whole frame, ``workers`` threads with 1 torch thread each."""
        saved = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            if self.workers == 1:
                self._work(0, do_f, do_g)
                return
            pool = shared_pool("correct", self.workers)
            futures = [pool.submit(_single_threaded, self._work, t, do_f, do_g)
                       for t in range(1, self.workers)]
            try:
                self._work(0, do_f, do_g)
            finally:   # never leave a worker writing into the buffers after returning
                for f in futures:
                    f.result()
        finally:
            torch.set_num_threads(saved)

    def correct(self, calibrated: np.ndarray, amplitude: np.ndarray, use_f: bool, use_g: bool,
                geodesic: GeodesicParams) -> tuple[np.ndarray, ...]:
        """One frame: (range, edges, confidence, calibrated, range_f, valid), each (H, W)."""
        h, w = self.shape
        nan = np.float32(np.nan)
        with self.lock:
            frame_planes(np.ascontiguousarray(calibrated, np.float32),
                         np.ascontiguousarray(amplitude, np.float32), self.consts, self.n_bins,
                         self.r_pad, self.la_pad, self.frame.bin_range,
                         self.frame.bin_amplitude, self.valid)
            valid = self.valid.copy()
            calib = np.where(valid, calibrated, nan).astype(np.float32)
            if not (use_f or use_g):
                return (calib, np.zeros((h, w), bool), valid.astype(np.float32), calib, calib,
                        valid)
            self.networks(use_f, use_g)
            range_f = calib
            if use_f:
                range_f = (calib + self.out.correction.reshape(h, w)).astype(np.float32)
            if not use_g:
                return (range_f, np.zeros((h, w), bool), valid.astype(np.float32), calib,
                        range_f, valid)
            if self.float32_nets is not None:
                self._recheck_unsure(np.ascontiguousarray(amplitude, np.float32), geodesic)
            best = self.out.best.reshape(h, w).copy()
            group = self.out.group.reshape(h, w).copy()
        confidence = np.where(valid, np.float32(1.0) - best, np.float32(0.0)).astype(np.float32)
        edges, filtered = _filter_from_best(geodesic, range_f, best, group)
        final = np.where(valid, filtered, nan).astype(np.float32)
        return final, edges, confidence, calib, range_f, valid

    def _recheck_unsure(self, amplitude: np.ndarray, params: GeodesicParams) -> None:
        """G again in float32 at the pixels whose edge decision a reduced precision's error
        could change (``edges.unsure_edge_decisions``), written over the heads' outputs.

        Why: the edge map decides at thresholds and local maxima; a pixel whose reduced score
        crosses one flips an edge, and the geodesic filter carries the flip to its neighbours
        (final range within 0.5 mm of float32 on 99.69 % of MD-Test's pixels in int8, 99.82 %
        in bfloat16, against the issue's 99.9 %; 99.993 % with it). The unsure pixels are a few
        per cent of an edge-rich frame and none where nothing can reach the high threshold;
        past ``RECHECK_MAX_SHARE`` the frame keeps its reduced edges.
        """
        from .edges import unsure_edge_decisions  # pulls in OpenCV/scipy, as _filter_from_best
        h, w = self.shape
        out = self.out
        unsure = unsure_edge_decisions(
            out.logit.reshape(h, w), out.margin.reshape(h, w), out.group.reshape(h, w),
            self.frame.valid.reshape(h, w), *self.recheck_error, low=params.edge_low,
            high=params.edge_high)
        idx = np.flatnonzero(unsure)
        self.rechecked = 0
        if idx.size > RECHECK_MAX_SHARE * np.count_nonzero(self.frame.valid):
            self.recheck_skipped += 1
            return
        self.rechecked = idx.size
        if idx.size == 0:
            return
        nets = self.float32_nets
        part = self.recheck_out
        # pixel-major rows, passed as the transposed view the GEMM reads in place
        x = torch.from_numpy(self.recheck_x).t()
        saved = torch.get_num_threads()
        if idx.size <= RECHECK_CHUNK:     # one chunk: waking a sleeping thread costs more
            torch.set_num_threads(1)
        try:
            for i0 in range(0, idx.size, RECHECK_CHUNK):
                chunk = idx[i0:i0 + RECHECK_CHUNK]
                n = chunk.size      # rows past n hold an earlier chunk's pixels: not read back
                size = next(c for c in RECHECK_CHUNKS if c >= n)
                encode_pixels(self.r_pad[None], self.la_pad[None], amplitude[None], chunk,
                              self.encoding, boundary_only=True, out=self.recheck_x)
                nets.heads(nets.first_layer(x[:, :size]), size, 0, self.recheck_frame, False,
                           True, part, self.recheck_scratch)
                out.best[chunk], out.group[chunk] = part.best[:n], part.group[:n]
                out.logit[chunk], out.margin[chunk] = part.logit[:n], part.margin[:n]
        finally:
            torch.set_num_threads(saved)


def _single_threaded(fn: Any, *args: Any) -> None:
    """Run ``fn(*args)`` with torch limited to 1 intra-op thread in this (worker) thread.

    Called unconditionally: besides torch's process-wide setting, ``set_num_threads`` sets the
    calling thread's OpenMP thread count, which oneDNN reads; a fresh pool thread otherwise keeps
    OpenMP's default (all cores) and every worker's GEMM would start its own team (measured:
    2 workers x 2 OpenMP threads on 2 cores, no wall-clock gain over 1 worker).
    """
    torch.set_num_threads(1)
    fn(*args)


def _filter_from_best(params: GeodesicParams, range_f: np.ndarray, best: np.ndarray,
                      group: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edge map from the heads' maximum and its group, then the geodesic filter of R_F."""
    # Imported here: edges/geodesic are separate modules that pull in OpenCV/scipy.
    from . import edges as edge_module
    from . import geodesic

    edge_map, _strength = edge_module.edge_map_from_best(best, group, low=params.edge_low,
                                                         high=params.edge_high)
    filtered = geodesic.geodesic_filter(range_f, edge_map, k=params.k, sigma=params.sigma,
                                        step=params.step)
    return np.asarray(edge_map, bool), np.asarray(filtered, np.float32)
