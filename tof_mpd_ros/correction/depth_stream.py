"""Correct a live depth/amplitude stream: decoding, conventions, crop and validation around
``correct``.

The corrector node is a thin ROS shell over this module: it hands over the fields of its
``sensor_msgs/Image`` messages (:func:`decode_depth`, :func:`decode_amplitude`) and intrinsics,
calls :meth:`DepthStreamCorrector.correct`, and encodes the result. Everything here is plain numpy
and testable without ROS.

Every rejected frame raises :class:`FrameRejected`, whose ``reason`` is one of
:data:`DROP_REASONS`: the node counts drops under these keys on ``/diagnostics``.

Either kind of model: the patch kind (F, G, geodesic filter) or the fcn kind (one network that
also predicts σ). For the fcn kind there is no edge map (all False), no geodesic constants, and
the confidence image the node publishes (:func:`confidence_image`) is the predicted σ in metres
instead of G's unitless boundary probability.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numba
import numpy as np
import torch

from ..camera import Intrinsics
from ..errors import InputError
from ..image_encoding import (
    DEPTH_MM_PER_UNIT,
    PIXEL_FORMATS,
    amplitude_to_float,
    depth_to_mm,
    image_to_array,
)
from ..validation import check_array
from . import geodesic
from .edges import edge_map_from_best
from .fcn import FCNCorrectionModel, check_engine_name
from .fcn import fcn_engine as fcn_engine_for
from .pipeline import (
    CorrectionModel,
    GeodesicParams,
    central_window,
    check_precision,
    correct,
    processed_window,
)

CONVENTIONS = ("z", "radial")

# Why a frame (or, for the pairing stage, one image) was dropped; the corrector node reports
# ``dropped_<reason>`` counters on /diagnostics under exactly these keys.
DROP_REASONS: dict[str, str] = {
    "no_amplitude": "a depth image found no amplitude image within sync_tolerance_s",
    "no_depth": "an amplitude image found no depth image within sync_tolerance_s",
    "out_of_order": "an image stamped at or before the last paired stamp",
    "queue_full": "the worker was busy; the oldest waiting pair was dropped",
    "no_camera_info": "no CameraInfo received yet",
    "bad_camera_info": "a CameraInfo with zero, negative or non-finite K or size",
    "bad_encoding": "an encoding that is not a REP 118 depth (or amplitude) encoding",
    "bad_image": "an image payload inconsistent with its height, width and step",
    "size_mismatch": "depth, amplitude and CameraInfo sizes differ, or the crop does not fit",
    "no_valid_pixel": "no valid (finite, > 0) pixel in the processed window",
    "internal_error": "an unexpected exception while correcting (a bug: please report it)",
}


class FrameRejected(InputError):
    """One input frame cannot be corrected; ``reason`` is a key of :data:`DROP_REASONS`."""

    def __init__(self, reason: str, message: str) -> None:
        if reason not in DROP_REASONS:
            raise ValueError(f"unknown drop reason {reason!r}")
        super().__init__(message)
        self.reason = reason


@dataclass
class StreamResult:
    """Corrected output for one input pair, in the input's depth convention.

    Attributes:
        depth_mm: (h, w) float32 corrected depth in mm (z-depth or radial range, like the
            input), NaN = invalid; h, w = the crop.
        edges: (h, w) bool boundary map from G (all False for the fcn kind).
        confidence: (h, w) float32 in [0, 1], unitless: the probability per G that the pixel is
            *not* on an object boundary, ``1 - max_k P_edge,k``; for the fcn kind
            ``1 - σ / max_sigma_mm`` clipped; 0 on invalid pixels (see
            :class:`~.pipeline.CorrectionResult`). The node publishes
            :func:`confidence_image`, which is σ in metres for the fcn kind.
        intrinsics: intrinsics of the cropped output images.
        valid_fraction: fraction of input pixels in the crop that were valid.
        input_mm: (h, w) float32 input depth of the same crop in mm, same convention,
            NaN where the input is invalid (NaN, inf or <= 0).
        amplitude: (h, w) float32 input amplitude of the crop, in the input's units (NaN =
            not finite).
        convention: ``"z"`` or ``"radial"``, the convention of ``depth_mm`` and ``input_mm``.
        sigma_mm: (h, w) float32 predicted standard deviation of ``depth_mm`` in mm, in the same
            convention (z: the radial σ times z / r, the ray's factor, so it is the σ of the
            z-depth published), NaN = invalid input; pixels whose σ exceeds the model's
            ``max_sigma_mm`` keep it (their depth is a sure neighbour's or NaN, see
            :func:`~.fcn.resolve_to_a_side`). The fcn kind only; None for the
            patch kind.
    """

    depth_mm: np.ndarray
    edges: np.ndarray
    confidence: np.ndarray
    intrinsics: Intrinsics
    valid_fraction: float
    input_mm: np.ndarray
    amplitude: np.ndarray
    convention: str
    sigma_mm: np.ndarray | None = None


def confidence_image(result: StreamResult) -> np.ndarray:
    """The corrector node's ``depth_corrected/confidence`` image of ``result``.

    Returns:
        (h, w) float32: for the patch kind ``result.confidence`` (unitless, in [0, 1], 0 on
        invalid pixels); for the fcn kind the predicted σ of the published depth in metres
        (``sigma_mm / 1000``, NaN on invalid pixels, like every metric image of REP 118).
    """
    if result.sigma_mm is None:
        return result.confidence
    return (result.sigma_mm.astype(np.float64) * 1e-3).astype(np.float32)


def points_m(depth_mm: np.ndarray, intrinsics: Intrinsics, convention: str) -> np.ndarray:
    """3-D points of a depth image, for an organized point cloud.

    Args:
        depth_mm: (H, W) float depth in mm, z-depth (``convention="z"``) or radial range
            (``"radial"``); NaN = invalid.
        intrinsics: intrinsics of this H x W image (e.g. the crop's).
        convention: ``"z"`` or ``"radial"``.

    Returns:
        (H, W, 3) float32 x, y, z in metres in the camera's optical frame (REP 103: x right,
        y down, z forward); all three NaN where ``depth_mm`` is NaN. For z-depth,
        ``x = (u - cx) z / fx``, ``y = (v - cy) z / fy`` (within float32 rounding).

    Raises:
        InputError: an unknown convention or a shape other than the intrinsics'.
    """
    if convention not in CONVENTIONS:
        raise InputError(f"convention must be one of {CONVENTIONS}, got {convention!r}")
    d = check_array("depth_mm", depth_mm, ndim=2, shape=intrinsics.shape, dtype_kind="fiu")
    range_mm = intrinsics.z_to_radial(d) if convention == "z" else d
    return (intrinsics.backproject(range_mm) * 1e-3).astype(np.float32)


def correction_m(corrected_mm: np.ndarray, input_mm: np.ndarray) -> np.ndarray:
    """What the correction changed: ``corrected - input``.

    Args:
        corrected_mm, input_mm: (H, W) float depth in mm, same convention; NaN = invalid.

    Returns:
        (H, W) float32 in metres, NaN where either is NaN.
    """
    c = check_array("corrected_mm", corrected_mm, ndim=2, dtype_kind="fiu")
    i = check_array("input_mm", input_mm, ndim=2, shape=c.shape, dtype_kind="fiu")
    return ((c.astype(np.float64) - i) * 1e-3).astype(np.float32)


def decode_depth(encoding: str, height: int, width: int, step: int, is_bigendian: bool,
                 data: bytes | bytearray | memoryview | np.ndarray) -> np.ndarray:
    """Decode the fields of a REP 118 depth image.

    Returns:
        (height, width) float32 depth in millimetres, NaN = invalid (0, NaN or inf in the
        message).

    Raises:
        FrameRejected: ``bad_encoding`` (not 32FC1/64FC1 metres or 16UC1/mono16 millimetres) or
            ``bad_image`` (payload size inconsistent with height, width and step).
    """
    if encoding not in DEPTH_MM_PER_UNIT:
        raise FrameRejected("bad_encoding", f"depth encoding {encoding!r} is not a REP 118 "
                            f"depth encoding; expected one of {sorted(DEPTH_MM_PER_UNIT)} "
                            "(32FC1/64FC1 in metres, 16UC1/mono16 in millimetres)")
    try:
        raw = image_to_array(encoding, height, width, step, is_bigendian, data)
    except InputError as err:
        raise FrameRejected("bad_image", f"depth image: {err}") from err
    return depth_to_mm(raw, encoding)


def decode_amplitude(encoding: str, height: int, width: int, step: int, is_bigendian: bool,
                     data: bytes | bytearray | memoryview | np.ndarray) -> np.ndarray:
    """Decode the fields of an amplitude (active IR) image.

    Returns:
        (height, width) float32 amplitude in sensor units, NaN = invalid.

    Raises:
        FrameRejected: ``bad_encoding`` (not a single-channel encoding) or ``bad_image``.
    """
    if encoding not in PIXEL_FORMATS:
        raise FrameRejected("bad_encoding", f"amplitude encoding {encoding!r} is not "
                            f"supported; expected one of {sorted(PIXEL_FORMATS)}")
    try:
        raw = image_to_array(encoding, height, width, step, is_bigendian, data)
    except InputError as err:
        raise FrameRejected("bad_image", f"amplitude image: {err}") from err
    return amplitude_to_float(raw)


class DepthStreamCorrector:
    """Applies a correction model of either kind to full camera frames.

    The processed window is the central crop of each input frame: ``crop`` if given, else the
    model's whole (H, W), and never more than the input (a frame smaller than the window is
    processed whole, as the central window of the model's pixels: :func:`central_window`). So
    full-sensor weights return full frames and still correct the paper's central 180x140 crop.
    Inputs in z-depth are converted to radial range for the model and the output back to
    z-depth, per pixel with the pinhole rays of the crop (lens distortion is not modelled).

    Args:
        model: the loaded correction model.
        input_convention: ``"z"`` when inputs are REP 118 z-depth, ``"radial"`` when they are
            radial ToF range; outputs follow the same convention.
        device: torch device for the networks (``"cpu"`` by default).
        threads: CPU threads for the networks and the geodesic filter; 0 keeps the libraries'
            defaults (one per core). Sets torch's *process-wide* intra-op thread count and
            numba's count of the calling thread, on every :meth:`correct` call (so a new
            corrector built on another thread takes effect on the thread that corrects). On a
            small, busy CPU one thread is faster than spinning OpenMP workers.
        geodesic: edge thresholds and geodesic filter constants replacing the model's (the
            weights file's); None keeps the model's. Patch kind only (an fcn model has none:
            its ``geodesic`` is None).
        crop: (width, height) of the processed central window; None = the model's frame.
        precision: one of :data:`~.pipeline.PRECISIONS` (the networks' arithmetic,
            :func:`~.pipeline.correct`; ``"int8"`` the patch kind only).
        fcn_engine: the fcn kind's executor (:func:`~.fcn.fcn_engine`); the patch kind
            ignores it.

    Raises:
        InputError: an unknown convention, precision or ``fcn_engine`` (or
            ``"onnxruntime"`` where it cannot run), ``threads`` < 0, ``geodesic`` for an fcn
            model, or a ``crop`` larger than the model's frame.
    """

    def __init__(self, model: CorrectionModel | FCNCorrectionModel, *,
                 input_convention: str = "z", device: str = "cpu", threads: int = 0,
                 geodesic: GeodesicParams | None = None,
                 crop: tuple[int, int] | None = None, precision: str = "float32",
                 fcn_engine: str = "auto") -> None:
        if input_convention not in CONVENTIONS:
            raise InputError(f"input_convention must be one of {CONVENTIONS}, "
                             f"got {input_convention!r}")
        if threads < 0:
            raise InputError(f"threads must be >= 0, got {threads}")
        self.threads = threads
        check_precision(model, precision)
        self.precision = precision
        check_engine_name(fcn_engine)
        if isinstance(model, FCNCorrectionModel):  # refused now, not per frame
            fcn_engine_for(fcn_engine, device, precision)
        self.fcn_engine = fcn_engine
        self.model = model
        self.kind = model.kind
        if isinstance(model, FCNCorrectionModel):
            if geodesic is not None:
                raise InputError("edge thresholds and geodesic constants apply to the patch "
                                 "kind only; this model is of kind 'fcn' (no G, no geodesic "
                                 "filter)")
            self.geodesic: GeodesicParams | None = None
        else:
            self.geodesic = model.geodesic if geodesic is None else geodesic
        self.input_convention = input_convention
        self.device = device
        self.crop_height, self.crop_width = model.shape
        self._windows: dict[tuple[int, int], CorrectionModel | FCNCorrectionModel] = {}
        if crop is not None:
            self.crop_width, self.crop_height = crop
            self._window_model(self.crop_height, self.crop_width)  # refuse a bad crop now

    def _window_model(self, height: int, width: int) -> CorrectionModel | FCNCorrectionModel:
        """The model on its central ``width`` x ``height`` window (cached: the patch kind's
        engine and buffers belong to the model object)."""
        key = (height, width)
        if key not in self._windows:
            self._windows[key] = central_window(self.model, width, height)
        return self._windows[key]

    def warm_up(self) -> float:
        """Correct one synthetic frame (a tilted plane about 500 mm away), so that the first
        real frame does not pay for JIT compilation and thread-pool start-up.

        Returns:
            The time it took, in seconds.
        """
        h, w = self.crop_height, self.crop_width
        v, u = np.mgrid[0:h, 0:w].astype(np.float32)
        depth = 500.0 + 0.5 * u + 0.2 * v
        amplitude = np.full((h, w), 1000.0, np.float32)
        t0 = time.perf_counter()
        self.correct(depth, amplitude, Intrinsics.from_fov(w, h, 60.0))
        if self.geodesic is None:  # the fcn kind: no edge or geodesic kernel to compile
            return time.perf_counter() - t0
        # A plane has no edges and no holes: also run the edge and geodesic kernels on a frame
        # that has both, so no code path is compiled on a live frame.
        edges = np.zeros((h, w), bool)
        edges[:, w // 2] = True
        holes = depth.copy()
        holes[h // 3, w // 3] = np.nan
        g = self.geodesic
        geodesic.geodesic_filter(holes, edges, k=g.k, sigma=g.sigma, step=g.step)
        best = np.where(edges, np.float32(0.9), np.float32(0.1)).astype(np.float32)
        edge_map_from_best(best, np.zeros((h, w), np.int64))
        return time.perf_counter() - t0

    def correct(self, depth_mm: np.ndarray, amplitude: np.ndarray,
                intrinsics: Intrinsics) -> StreamResult:
        """Correct one frame.

        Args:
            depth_mm: (H, W) float32 depth in mm in ``input_convention``, NaN = invalid.
            amplitude: (H, W) float32 amplitude, NaN = invalid.
            intrinsics: intrinsics of the H x W input images.

        Raises:
            FrameRejected: ``size_mismatch`` (depth, amplitude and intrinsics sizes differ, or
                the crop does not fit) or ``no_valid_pixel`` (nothing to correct in the crop).
            InputError: an array is not 2-D numeric.
        """
        depth_mm = check_array("depth_mm", depth_mm, ndim=2, dtype_kind="fiu")
        amplitude = check_array("amplitude", amplitude, ndim=2, dtype_kind="fiu")
        if depth_mm.shape != amplitude.shape:
            raise FrameRejected("size_mismatch", f"depth is {_wxh(depth_mm.shape)} but "
                                f"amplitude is {_wxh(amplitude.shape)}")
        if depth_mm.shape != intrinsics.shape:
            raise FrameRejected("size_mismatch", f"images are {_wxh(depth_mm.shape)} but "
                                f"CameraInfo says {_wxh(intrinsics.shape)}")
        height, width = processed_window(self.model.shape, depth_mm.shape,
                                         (self.crop_width, self.crop_height))
        rows, cols = intrinsics.crop_window(width, height)
        crop_intrinsics = intrinsics.crop(width, height)
        depth = depth_mm[rows, cols].astype(np.float32)
        amp = amplitude[rows, cols].astype(np.float32)
        measured = np.isfinite(depth) & (depth > 0)
        valid = measured & np.isfinite(amp)
        if not valid.any():
            raise FrameRejected("no_valid_pixel", f"no valid pixel in the central "
                                f"{width}x{height} window (all depth "
                                "NaN, inf or 0, or amplitude not finite)")
        range_mm = (crop_intrinsics.z_to_radial(depth) if self.input_convention == "z"
                    else depth)
        if self.threads:
            if torch.get_num_threads() != self.threads:
                torch.set_num_threads(self.threads)
            numba.set_num_threads(min(self.threads, numba.config.NUMBA_NUM_THREADS))
        result = correct(self._window_model(height, width), range_mm, amp, device=self.device,
                         geodesic=self.geodesic, precision=self.precision,
                         fcn_engine=self.fcn_engine)
        out, sigma = result.range_mm, result.sigma_mm
        if self.input_convention == "z":
            out = crop_intrinsics.radial_to_z(out)
            if sigma is not None:  # z = r * (z / r) per pixel: σ scales alike
                sigma = crop_intrinsics.radial_to_z(sigma)
        return StreamResult(out.astype(np.float32), result.edges, result.confidence,
                            crop_intrinsics, float(valid.mean()),
                            np.where(measured, depth, np.float32(np.nan)), amp,
                            self.input_convention,
                            None if sigma is None else sigma.astype(np.float32))


def _wxh(shape: tuple[int, ...]) -> str:
    return f"{shape[1]}x{shape[0]} (W x H)"
