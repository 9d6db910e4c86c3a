"""The corrector node class: a thin ROS shell over :class:`DepthStreamCorrector`.

Subscriptions only pair messages and queue them; a worker thread decodes, corrects and publishes
(bounded drop-oldest queue, every drop counted by reason and reported on ``/diagnostics``).

Every parameter but the QoS ones changes while the node runs. A change that alters the
correction (weights file, device, convention, threads, edge and geodesic knobs) is built whole in
the on-set callback, a new weights file loaded and warmed up there, so a bad value is refused with
its reason and the node keeps the correction it had; the worker picks the new one up between
frames (it reads :attr:`CorrectorNode.stream` once per frame).

Drop reasons are the keys of :data:`~tof_mpd_ros.correction.depth_stream.DROP_REASONS`. The
pairing stage (``no_amplitude``, ``no_depth``, ``out_of_order``) counts *images*; every later
stage counts depth/amplitude *pairs*.

Weights of either kind: the patch kind (F, G, geodesic filter) or the fcn kind (one network
with a predicted σ). With fcn weights the edge image is all 0, the confidence image is the
predicted σ of the published depth in metres (NaN on invalid pixels), and the patch-only
parameters (:data:`PATCH_ONLY_PARAMETERS`) are ignored, with one warning in the log each time
a correction is built with one of them set away from its default. A weights file of the other
kind can be loaded at run time like any other (``weights_path``).
"""

from __future__ import annotations

import collections
import dataclasses
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.exceptions import InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from ..camera import Intrinsics
from ..correction.default_weights import default_weights_path
from ..correction.depth_stream import (
    DROP_REASONS,
    DepthStreamCorrector,
    FrameRejected,
    StreamResult,
    confidence_image,
    correction_m,
    decode_amplitude,
    decode_depth,
    points_m,
)
from ..correction.fcn import FCNCorrectionModel
from ..correction.pipeline import CorrectionModel, GeodesicParams
from ..correction.weights import load_weights
from ..errors import InputError, TofMpdError
from ..image_encoding import mm_to_depth
from ..machine import slow_precision
from .pairing import LatestQueueWorker, StampPairer, last_resort_report
from .parameters import ParameterSpec as P
from .parameters import declare, refuse_retired_parameters
from .qos import overridable_publisher, overridable_subscription, publisher_qos, subscription_qos
from .ros_messages import (
    cropped_camera_info,
    image_message,
    intrinsics_of,
    point_cloud_message,
    stamp_ns,
)

# Said by every QoS parameter: a live endpoint's QoS cannot change.
_QOS_READ_ONLY = " Read-only: QoS cannot change on a live endpoint; set it at start-up."
# Said by every parameter of G and the geodesic filter (PATCH_ONLY_PARAMETERS).
_PATCH_ONLY = " Patch kind only: ignored (with a warning) for weights of the fcn kind."

# The node's parameters; config/corrector.yaml mirrors these defaults (a test keeps them equal).
# All but the QoS ones change at run time (``ros2 param set``).
PARAMETERS = (
    P("weights_path", "", "Correction weights (.npz); empty = the weights shipped with the "
      "package. A new file is loaded and tried when set; one that cannot be is refused and "
      "the node keeps the weights it has."),
    P("input_convention", "z", "z: input holds REP 118 z-depth; radial: radial ToF range. "
      "The output follows the input.", choices=("z", "radial")),
    P("output_encoding", "input", "Encoding of the corrected depth: input (same as the "
      "input), 32FC1 (metres) or 16UC1 (millimetres).",
      choices=("input", "32FC1", "16UC1")),
    P("device", "cpu", "Torch device for the networks (cpu, cuda, cuda:0...); a device the "
      "model does not run on is refused."),
    # Aliases of the standard QoS overrides (docs/nodes.md): they set the profile that
    # qos_overrides.<topic>.* parameters default to, so old launch files keep working.
    P("input_reliability", "best_effort", "Alias: default reliability of the three input "
      "subscriptions (sensor-data QoS: best_effort); qos_overrides.<topic>.subscription."
      "reliability overrides it per topic." + _QOS_READ_ONLY,
      choices=("best_effort", "reliable"), read_only=True),
    P("output_reliability", "reliable", "Alias: default reliability of the outputs "
      "(reliable, like image_pipeline: default-QoS and sensor-data subscribers both match); "
      "qos_overrides.<topic>.publisher.reliability overrides it per topic." + _QOS_READ_ONLY,
      choices=("best_effort", "reliable"), read_only=True),
    P("input_depth", 5, "Alias: default history depth of the three input subscriptions "
      "(sensor-data QoS: 5); qos_overrides.<topic>.subscription.depth overrides it per "
      "topic." + _QOS_READ_ONLY, min_value=1, max_value=1000, read_only=True),
    P("precision", "float32", "Arithmetic of the networks: float32, bfloat16 (CPUs with "
      "AVX512-BF16 or AMX), or int8 (patch kind: the first-layer GEMM in int8 on VNNI, "
      "1.3-1.4x faster end to end, docs/performance.md). Both keep R_F within 0.5 mm of "
      "float32 on >= 99.99 % of the pixels and the accuracy within 5 mm; the edge map flips "
      "at a few threshold pixels, which moves the final range by > 0.5 mm on 0.1-0.5 % of "
      "the pixels. Without those instructions (AVX2 only) a reduced precision is right but "
      "6-24x slower than float32, and the node logs a warning.",
      choices=("float32", "bfloat16", "int8")),
    P("fcn_engine", "auto", "Executor of the fcn kind's network: auto (ONNX Runtime on the "
      "CPU in float32 on 2+ threads, where it measured faster; torch otherwise), torch, or "
      "onnxruntime (refused where it cannot run: another device, bfloat16). Outputs agree "
      "within 1e-5 mm. Ignored for the patch kind.",
      choices=("auto", "torch", "onnxruntime")),
    P("crop_width", 0, "Width of the processed central window of each frame, pixels; 0 = the "
      "weights' whole frame (the shipped weights: the full 320x240 sensor). The paper's "
      "crop is 180 x 140. A frame smaller than the window is processed whole.",
      min_value=0, max_value=4096),
    P("crop_height", 0, "Height of the processed central window, pixels; 0 = the weights' "
      "whole frame.", min_value=0, max_value=4096),
    P("threads", 1, "CPU threads for the networks (torch) and the geodesic filter (numba); "
      "0 = the libraries' default, one per core. One keeps 30 Hz at 180x140 on a 2-core "
      "machine and leaves the other cores to the rest of the robot's software.",
      min_value=0, max_value=256),
    P("parallel_frames", 1, "Frames corrected at once, each on its own worker thread with "
      "`threads` threads; results are published in the order the frames arrived. Each "
      "frame takes as long as before, so the throughput rises, not the latency: with "
      "threads 1 and parallel_frames 2 a 2-core machine corrects the fcn kind at 320x240 "
      "about 1.7x as many frames per second as one frame on 2 threads (docs/performance.md). "
      "Fixed at start-up.", min_value=1, max_value=16, read_only=True),
    P("sync_tolerance_s", 0.005, "Largest stamp difference at which depth and amplitude "
      "pair.", min_value=0.0, max_value=1.0),
    P("queue_size", 2, "Pairs waiting for the worker; the oldest is dropped when full (also "
      "when the queue is made smaller than it is full).", min_value=1, max_value=100),
    P("diagnostics_period_s", 1.0, "Period of /diagnostics messages.", min_value=0.05,
      max_value=60.0),
    # The correction's knobs; their defaults stand for the weights file's values, which the
    # trainer chose on validation frames (the node logs the values in use).
    P("edge_low", -1.0, "Hysteresis: lower threshold on G's edge probability (0-1); a pixel "
      "above it is an edge when connected to one above edge_high. Negative = the weights "
      "file's value (0.3 untrained)." + _PATCH_ONLY, min_value=-1.0, max_value=1.0),
    P("edge_high", -1.0, "Hysteresis: upper threshold on G's edge probability (0-1, >= "
      "edge_low); every pixel above it is an edge. Negative = the weights file's value "
      "(0.6 untrained)." + _PATCH_ONLY, min_value=-1.0, max_value=1.0),
    P("geodesic_k", 0, "Neighbours K the geodesic filter averages per pixel (the paper's "
      "81); 0 = the weights file's value." + _PATCH_ONLY, min_value=0, max_value=1000),
    P("geodesic_sigma", 0.0, "Bandwidth sigma of the geodesic filter's Gaussian weights, in "
      "grid steps of the filter (pixels; the paper's 2); 0 = the weights file's value."
      + _PATCH_ONLY, min_value=0.0, max_value=100.0),
)
# The parameters of the patch kind's G and geodesic filter: weights of the fcn kind have
# neither, so there they are ignored (logged once per correction built, not refused, so that
# one parameter file serves weights of either kind).
PATCH_ONLY_PARAMETERS = ("edge_low", "edge_high", "geodesic_k", "geodesic_sigma")
# Parameters whose change builds a new correction before it is accepted; the first two load
# the weights file again (a new model, warmed up on the device before the worker sees it).
RELOAD_PARAMETERS = ("weights_path", "device")
REBUILD_PARAMETERS = (*RELOAD_PARAMETERS, "input_convention", "precision", "fcn_engine",
                      "crop_width",
                      "crop_height",
                      "threads", "edge_low",
                      "edge_high", "geodesic_k", "geodesic_sigma")

# Topic names, relative like image_pipeline's: users move them with namespaces
# (``-r __ns:=/tof``) and remapping (``-r depth/image_raw:=/camera/depth``), not parameters.
TOPICS = {"depth": "depth/image_raw", "amplitude": "amplitude/image_raw",
          "camera_info": "depth/camera_info", "output": "depth_corrected/image",
          "edges": "depth_corrected/edges", "confidence": "depth_corrected/confidence",
          "output_camera_info": "depth_corrected/camera_info",
          "points": "depth_corrected/points", "input_points": "depth_corrected/input_points",
          "correction": "depth_corrected/correction"}
# What the node publishes, key of TOPICS -> message type (/diagnostics besides).
PUBLISHED = {"output": Image, "edges": Image, "confidence": Image,
             "output_camera_info": CameraInfo, "points": PointCloud2,
             "input_points": PointCloud2, "correction": Image}
# Outputs computed only while something subscribes to them: the default cost is unchanged.
ON_DEMAND = ("points", "input_points", "correction")
# The topic parameters these names replaced (issue 14): setting one stops the node with the
# remapping to use instead, rather than being ignored and leaving the node on the wrong topic.
RETIRED_TOPIC_PARAMETERS = {"depth_topic": TOPICS["depth"],
                            "amplitude_topic": TOPICS["amplitude"],
                            "camera_info_topic": TOPICS["camera_info"],
                            "output_topic": TOPICS["output"]}

# Unmatched images kept per stream while they wait for a partner.
PAIRING_HISTORY = 8
# This many out-of-order images in a row are a jump back in time (a recording replayed from
# its start, a restarted driver): pairing starts again instead of dropping everything after.
RESET_AFTER_OUT_OF_ORDER = 2 * PAIRING_HISTORY
# A stream silent for this long while depth images arrive is reported as missing.
STALE_AFTER_S = 1.0
# The worker waits this long for the first CameraInfo before dropping a pair.
CAMERA_INFO_WAIT_S = 1.0
# Each drop reason is logged at once, then at most every LOG_EVERY_S (with the count).
LOG_EVERY_S = 5.0
# How long a stop waits for the frame in progress (many seconds on a loaded machine at most).
WORKER_STOP_S = 30.0


@dataclass
class _Pair:
    """A paired depth + amplitude message, as queued for the worker."""

    stamp_ns: int
    depth: Image
    amplitude: Image
    received: float  # time.monotonic() when the pair formed, seconds


class CorrectorStats:
    """Thread-safe counters, stream ages and latency history for ``/diagnostics``.

    Latency is measured inside the node: from the moment a pair forms (its second image
    arrives) to the moment its outputs are published, in milliseconds.
    """

    STREAMS = ("depth", "amplitude", "camera_info")

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.published = 0
        self.drops: collections.Counter[str] = collections.Counter()
        self.received: collections.Counter[str] = collections.Counter()
        self.last_received: dict[str, float] = {}
        self.latencies_ms: collections.deque[float] = collections.deque(maxlen=1000)
        self.last_error = ""
        self._stamps: collections.deque[float] = collections.deque(maxlen=100)
        self._period_drops: collections.Counter[str] = collections.Counter()
        self._period_error = ""
        self._period_published = 0
        self.pairing_resets = 0

    def note_reset(self) -> None:
        """The pairer restarted after a jump back in time."""
        with self._lock:
            self.pairing_resets += 1

    def receive(self, stream: str) -> None:
        """An image or CameraInfo of ``stream`` (one of :attr:`STREAMS`) arrived."""
        with self._lock:
            self.received[stream] += 1
            self.last_received[stream] = time.monotonic()

    def drop(self, reason: str, message: str) -> int:
        """Count one drop; returns the total for ``reason``."""
        with self._lock:
            self.drops[reason] += 1
            self._period_drops[reason] += 1
            self.last_error = self._period_error = f"{reason}: {message}"
            return self.drops[reason]

    def done(self, latency_ms: float) -> None:
        """One pair corrected and published ``latency_ms`` after it formed."""
        with self._lock:
            self.published += 1
            self._period_published += 1
            self.latencies_ms.append(latency_ms)
            self._stamps.append(time.monotonic())

    def age_s(self, stream: str, now: float) -> float | None:
        """Seconds since ``stream`` last arrived; None if it never did."""
        with self._lock:
            last = self.last_received.get(stream)
        return None if last is None else now - last

    def snapshot(self) -> tuple[dict[str, str], collections.Counter[str], int, str]:
        """Diagnostic values, plus the drops, publications and last error since the previous
        snapshot (which starts a new period)."""
        now = time.monotonic()
        with self._lock:
            lat = np.asarray(self.latencies_ms, dtype=np.float64)
            span = self._stamps[-1] - self._stamps[0] if len(self._stamps) > 1 else 0.0
            rate = (len(self._stamps) - 1) / span if span > 0 else 0.0
            if self._stamps and now - self._stamps[-1] > STALE_AFTER_S:
                rate = 0.0
            values = {"published": str(self.published), "rate_hz": f"{rate:.2f}"}
            for q in (50, 99):
                values[f"latency_p{q}_ms"] = (f"{np.percentile(lat, q):.2f}" if lat.size
                                              else "nan")
            values["latency_max_ms"] = f"{lat.max():.2f}" if lat.size else "nan"
            for stream in self.STREAMS:
                values[f"received_{stream}"] = str(self.received[stream])
                last = self.last_received.get(stream)
                values[f"{stream}_age_s"] = "never" if last is None else f"{now - last:.2f}"
            values["pairing_resets"] = str(self.pairing_resets)
            values["dropped_total"] = str(sum(self.drops.values()))
            values.update({f"dropped_{k}": str(self.drops[k]) for k in DROP_REASONS})
            values["last_error"] = self.last_error
            period = (self._period_drops, self._period_published, self._period_error)
            self._period_drops = collections.Counter()
            self._period_published = 0
            self._period_error = ""
        return values, *period


@dataclass(frozen=True)
class _Staged:
    """A correction built and checked by the on-set callback, waiting for the post-set one."""

    changes: dict[str, Any]  # the rebuilding parameters of that change, name -> value
    stream: DepthStreamCorrector
    weights: str


class CorrectorNode(Node):
    """Subscribes to depth + amplitude + CameraInfo, publishes the corrected depth.

    Subscribes to ``depth/image_raw``, ``amplitude/image_raw`` and ``depth/camera_info``;
    publishes ``depth_corrected/image`` and beside it ``edges`` (mono8, 255 = boundary from
    G), ``confidence`` (32FC1, unitless in [0, 1]: the probability per G that the pixel is not
    on an object boundary, ``1 - max_k P_edge,k``, where mixed pixels and over-smoothing make
    ToF least reliable; 0 on invalid pixels. With weights of the fcn kind: the predicted
    standard deviation of the published depth in metres, NaN on invalid pixels, and ``edges``
    all 0) and ``camera_info`` (the crop's); while something
    subscribes to them, ``points`` and ``input_points`` (organized PointCloud2 of the
    corrected and the input depth of the crop: x, y, z float32 metres in the optical frame,
    intensity = amplitude, NaN x/y/z for invalid pixels) and ``correction`` (32FC1 metres,
    corrected - input, NaN where either is invalid). Every output carries the input depth
    image's header (stamp, frame_id). And ``/diagnostics``.

    Args:
        **node_options: passed to :class:`rclpy.node.Node` (``context``, ``namespace``,
            ``parameter_overrides``..., e.g. to run the node inside a test process).

    Raises:
        WeightsError: the weights file is missing or unreadable.
        TofMpdError: a parameter is out of range, or the model does not run on ``device``.
        (The executable turns these into one line on stderr and exit code 2.)
    """

    def __init__(self, **node_options: Any) -> None:
        super().__init__("corrector", **node_options)
        refuse_retired_parameters(self, RETIRED_TOPIC_PARAMETERS)
        self._staged: _Staged | None = None
        try:
            self.params = declare(self, PARAMETERS, check=self._check_change)
        except (ValueError, InvalidParameterValueException) as err:
            raise InputError(f"bad parameter: {err}") from err
        self.weights = _weights_text(self.params)
        model = load_weights(Path(self.weights))  # WeightsError: refuse to start
        try:
            stream = _stream_for(model, self.params)
        except InputError as err:
            raise InputError(f"bad parameter: {err}") from err
        warm_s = _warm_up(stream, self.weights)  # a bad device fails here
        self.stream = stream  # the worker reads it once per frame; replaced whole, never edited
        self.stats = CorrectorStats()
        self._camera_info: CameraInfo | None = None
        self._camera_info_ready = threading.Event()
        self._pair_lock = threading.Lock()
        self._stopping = threading.Event()
        self._last_logged: dict[str, float] = {}
        self.pairer: StampPairer[Image, Image] = StampPairer(
            round(self.params["sync_tolerance_s"] * 1e9), history=PAIRING_HISTORY,
            reset_after=RESET_AFTER_OUT_OF_ORDER)
        self.worker: LatestQueueWorker[_Pair] = LatestQueueWorker(
            self._process, maxsize=self.params["queue_size"], on_error=self._worker_error,
            workers=self.params["parallel_frames"])
        qos = publisher_qos(self.params["output_reliability"])
        in_qos = subscription_qos(self.params["input_reliability"], self.params["input_depth"])
        self.pubs = {key: overridable_publisher(self, kind, TOPICS[key], qos)
                     for key, kind in PUBLISHED.items()}
        self.pub_depth = self.pubs["output"]
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        subscriptions = {
            "depth": overridable_subscription(self, Image, TOPICS["depth"], self._on_depth,
                                              in_qos),
            "amplitude": overridable_subscription(self, Image, TOPICS["amplitude"],
                                                  self._on_amplitude, in_qos),
            "camera_info": overridable_subscription(self, CameraInfo, TOPICS["camera_info"],
                                                    self._on_info, in_qos)}
        # Resolved names (namespace and remapping applied), for log and diagnostic messages.
        self.topics = {k: sub.topic_name for k, sub in subscriptions.items()}
        self.add_post_set_parameters_callback(self._on_parameters_set)
        self._diagnostics_timer = self.create_timer(self.params["diagnostics_period_s"],
                                                    self._publish_diagnostics)
        self.get_logger().info(
            f"correcting {self.topics['depth']} + {self.topics['amplitude']} -> "
            f"{self.pub_depth.topic_name} ({_describe(self.stream, self.weights)}); "
            f"warm-up frame {warm_s * 1e3:.0f} ms")
        self._warn_adopted(self.stream)

    def _warn_adopted(self, stream: DepthStreamCorrector) -> None:
        """Warnings about the correction just adopted: patch-only parameters it ignores, and a
        reduced precision this CPU has no instructions for (right, but slower than float32)."""
        ignored = ignored_parameters(stream, self.params)
        if ignored:
            self.get_logger().warning(
                f"ignoring {_assignments(ignored)}: weights of the fcn kind have no G and no "
                "geodesic filter (these parameters apply to the patch kind only)")
        if str(stream.device).split(":")[0] == "cpu":
            slow = slow_precision(stream.precision)
            if slow is not None:
                self.get_logger().warning(slow)

    # -- parameters ---------------------------------------------------------------------
    def _check_change(self, parameters: list[Parameter]) -> str | None:
        """On-set check: build the correction a change asks for, or say why it cannot be.

        Runs in the executor thread before the change is accepted. A new weights file or device
        is loaded and warmed up here; the result waits in ``_staged`` for
        :meth:`_on_parameters_set`, which swaps it in whole.
        """
        self._staged = None
        changes = _rebuilding(parameters)
        if not changes:
            return None
        values = {**self.params, **changes}
        weights = _weights_text(values)
        try:
            if any(name in changes for name in RELOAD_PARAMETERS):
                stream = _stream_for(load_weights(Path(weights)), values)
                _warm_up(stream, weights)
            else:
                stream = _stream_for(self.stream.model, values)
        except Exception as err:  # whatever the cause, refuse the change, never the node
            why = str(err) if isinstance(err, TofMpdError) else f"{type(err).__name__}: {err}"
            return f"refused {_assignments(changes)}: {why}; still correcting with {self.weights}"
        self._staged = _Staged(changes, stream, weights)
        return None

    def _on_parameters_set(self, parameters: list[Parameter]) -> None:
        for p in parameters:
            if p.name in self.params:
                self.params[p.name] = p.value
        names = {p.name for p in parameters}
        staged, self._staged = self._staged, None
        if staged is not None and staged.changes == _rebuilding(parameters):
            self.stream, self.weights = staged.stream, staged.weights
            self.get_logger().info(
                f"now correcting with {_describe(staged.stream, staged.weights)}")
            self._warn_adopted(staged.stream)
        if "sync_tolerance_s" in names:
            with self._pair_lock:
                self.pairer.tolerance_ns = round(self.params["sync_tolerance_s"] * 1e9)
        if "queue_size" in names:
            for _ in range(self.worker.resize(self.params["queue_size"])):
                self._drop("queue_full", "queue_size was lowered below the pairs waiting: the "
                           "oldest were dropped")
        if "diagnostics_period_s" in names:
            self._diagnostics_timer.timer_period_ns = round(
                self.params["diagnostics_period_s"] * 1e9)
            self._diagnostics_timer.reset()  # the next message one new period from now

    # -- callbacks: cheap, never block --------------------------------------------------
    def _on_info(self, msg: CameraInfo) -> None:
        self.stats.receive("camera_info")
        self._camera_info = msg
        self._camera_info_ready.set()

    def _on_depth(self, msg: Image) -> None:
        self.stats.receive("depth")
        self._pair(msg, left=True)

    def _on_amplitude(self, msg: Image) -> None:
        self.stats.receive("amplitude")
        self._pair(msg, left=False)

    def _pair(self, msg: Image, *, left: bool) -> None:
        stamp = stamp_ns(msg)
        with self._pair_lock:
            s = self.pairer.stats
            before = (s.unmatched_left, s.unmatched_right, s.out_of_order_dropped, s.resets)
            last_ns = self.pairer.last_emitted_ns
            if left:
                pair = self.pairer.add_left(stamp, msg)
            else:
                pair = self.pairer.add_right(stamp, msg)
            after = (s.unmatched_left, s.unmatched_right, s.out_of_order_dropped, s.resets)
        tol_ms = self.params["sync_tolerance_s"] * 1e3
        for _ in range(after[0] - before[0]):
            self._drop("no_amplitude", f"a depth image found no amplitude image on "
                       f"{self.topics['amplitude']} within {tol_ms:g} ms of its stamp")
        for _ in range(after[1] - before[1]):
            self._drop("no_depth", f"an amplitude image found no depth image on "
                       f"{self.topics['depth']} within {tol_ms:g} ms of its stamp")
        if after[2] > before[2]:
            kind = "depth" if left else "amplitude"
            self._drop("out_of_order", f"{kind} image stamped {_stamp_text(stamp)} is not newer "
                       f"than the last paired stamp {_stamp_text(last_ns)}")
        if after[3] > before[3]:
            self.stats.note_reset()
            self.get_logger().warning(
                f"stamps jumped back by {(last_ns - stamp) / 1e9:.3f} s "
                f"({RESET_AFTER_OUT_OF_ORDER} out-of-order images in a row): pairing restarted "
                f"at {_stamp_text(stamp)}")
        if pair is not None:
            dropped_before = self.worker.dropped
            self.worker.submit(_Pair(pair[0], pair[1], pair[2], time.monotonic()))
            if self.worker.dropped > dropped_before:
                self._drop("queue_full", "the worker is still busy: the oldest waiting pair "
                           f"was dropped (queue_size {self.params['queue_size']})")

    # -- worker thread ------------------------------------------------------------------
    def _process(self, pair: _Pair) -> Callable[[], None] | None:
        """Correct one pair; returns the step that publishes it (the worker runs those in
        the order the pairs arrived), None when the pair was dropped."""
        stream = self.stream  # one correction for the whole frame, whatever a change swaps in
        info = self._camera_info
        if info is None and self._camera_info_ready.wait(CAMERA_INFO_WAIT_S):
            info = self._camera_info
        if info is None:
            self._drop("no_camera_info", "no CameraInfo on "
                       f"{self.topics['camera_info']} yet")
            return None
        try:
            intrinsics = _intrinsics(info)
            depth = decode_depth(*_fields(pair.depth))
            amplitude = decode_amplitude(*_fields(pair.amplitude))
            result = stream.correct(depth, amplitude, intrinsics)
        except FrameRejected as err:
            self._drop(err.reason, str(err))
            return None
        return lambda: self._finish(pair, result, info)

    def _finish(self, pair: _Pair, result: StreamResult, info: CameraInfo) -> None:
        if self._stopping.is_set():  # the node is going: its publishers may already be gone
            return
        self._publish(pair, result, info)
        self.stats.done((time.monotonic() - pair.received) * 1e3)

    def _publish(self, pair: _Pair, result: StreamResult, info: CameraInfo) -> None:
        header = pair.depth.header
        encoding = self.params["output_encoding"]
        if encoding == "input":
            encoding = "16UC1" if pair.depth.encoding == "mono16" else pair.depth.encoding
        depth = mm_to_depth(result.depth_mm, encoding)
        self.pub_depth.publish(image_message(depth, encoding, header=header))
        edges = result.edges.astype(np.uint8) * np.uint8(255)
        self.pubs["edges"].publish(image_message(edges, "mono8", header=header))
        self.pubs["confidence"].publish(image_message(confidence_image(result), "32FC1",
                                                      header=header))
        self.pubs["output_camera_info"].publish(
            cropped_camera_info(info, result.intrinsics, header=header))
        for key in ON_DEMAND:
            publisher = self.pubs[key]
            if publisher.get_subscription_count() > 0:
                publisher.publish(on_demand_message(key, result, header))

    def _worker_error(self, err: BaseException) -> None:
        self._drop("internal_error", repr(err))

    # -- reporting ----------------------------------------------------------------------
    def _drop(self, reason: str, message: str) -> None:
        """Count a drop under ``reason``; log the first at once, then every LOG_EVERY_S.

        Called from the worker's error path too, so it must not raise: counting cannot, and
        a logging failure is reported on stderr instead of propagating.
        """
        count = self.stats.drop(reason, message)
        now = time.monotonic()
        if now - self._last_logged.get(reason, -np.inf) < LOG_EVERY_S:
            return
        self._last_logged[reason] = now
        text = f"dropped ({reason}, {count} so far): {message}"
        try:
            self._log_drop(reason, text)
        except Exception as err:  # never let a report take the worker (or a callback) down
            last_resort_report(f"[corrector] {text} (logging failed: {err!r})")

    def _log_drop(self, reason: str, text: str) -> None:
        # One call site per severity: rclpy raises ValueError when the severity logged from
        # one line changes between calls.
        if reason == "internal_error":
            self.get_logger().error(text)
        else:
            self.get_logger().warning(text)

    def _missing_stream(self, now: float) -> str:
        """Why depth images cannot pair (a silent partner stream), or ``""``."""
        depth_age = self.stats.age_s("depth", now)
        if depth_age is None or depth_age > STALE_AFTER_S:
            return ""
        for stream, topic in (("amplitude", self.topics["amplitude"]),
                              ("camera_info", self.topics["camera_info"])):
            age = self.stats.age_s(stream, now)
            if age is None:
                return f"depth images arrive but no {stream} was ever received on {topic}"
            if age > STALE_AFTER_S:
                return (f"depth images arrive but nothing on {topic} for {age:.1f} s")
        return ""

    def _publish_diagnostics(self) -> None:
        now = time.monotonic()
        values, period_drops, period_published, period_error = self.stats.snapshot()
        missing = self._missing_stream(now)
        n_dropped = sum(period_drops.values())
        dropped = ""
        if n_dropped:
            reasons = ", ".join(f"{k} {v}" for k, v in sorted(period_drops.items()))
            dropped = f"dropped {n_dropped} ({reasons}); last: {period_error}"
        if missing:
            level, message = DiagnosticStatus.ERROR, "; ".join(filter(None, (missing, dropped)))
        elif n_dropped:
            level = DiagnosticStatus.WARN if period_published else DiagnosticStatus.ERROR
            message = dropped
        elif self.stats.age_s("depth", now) is None:
            level = DiagnosticStatus.WARN
            message = f"waiting for depth images on {self.topics['depth']}"
        else:
            level = DiagnosticStatus.OK
            message = (f"correcting at {values['rate_hz']} Hz, latency p99 "
                       f"{values['latency_p99_ms']} ms")
        status = DiagnosticStatus(level=level, name="tof_mpd_ros: corrector",
                                  hardware_id=self.topics["depth"], message=message)
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(msg)

    def destroy_node(self) -> None:
        # Called while the context is still valid (ros_runtime.spin_node): the frame in
        # progress finishes (unpublished) before the publishers and the context go.
        self._stopping.set()
        self.worker.stop(timeout=WORKER_STOP_S, discard=True)
        super().destroy_node()


def on_demand_message(key: str, result: StreamResult, header: Any) -> PointCloud2 | Image:
    """The message of one of :data:`ON_DEMAND` for ``result``, with ``header``.

    ``points`` / ``input_points``: the organized cloud of the corrected / input depth of the
    crop (through the crop's intrinsics, in ``result.convention``), intensity = the amplitude;
    ``correction``: corrected - input, 32FC1 metres.
    """
    if key == "correction":
        return image_message(correction_m(result.depth_mm, result.input_mm), "32FC1",
                             header=header)
    depth_mm = result.depth_mm if key == "points" else result.input_mm
    return point_cloud_message(points_m(depth_mm, result.intrinsics, result.convention),
                               result.amplitude, header=header)


def effective_geodesic(weights: GeodesicParams, values: Mapping[str, Any]) -> GeodesicParams:
    """The weights file's edge thresholds and geodesic constants with the node's parameters.

    A negative ``edge_low`` / ``edge_high``, ``geodesic_k`` 0 and ``geodesic_sigma`` 0 keep
    the file's value.

    Raises:
        InputError: ``edge_low`` above ``edge_high`` (either the file's or a parameter).
    """
    low = weights.edge_low if values["edge_low"] < 0 else float(values["edge_low"])
    high = weights.edge_high if values["edge_high"] < 0 else float(values["edge_high"])
    if low > high:
        raise InputError(f"edge_low {low:g} is above edge_high {high:g} (a negative value "
                         f"stands for the weights file's: {weights.edge_low:g} / "
                         f"{weights.edge_high:g})")
    k, sigma = values["geodesic_k"], values["geodesic_sigma"]
    return dataclasses.replace(weights, edge_low=low, edge_high=high,
                               k=weights.k if k == 0 else int(k),
                               sigma=weights.sigma if sigma == 0 else float(sigma))


def _stream_for(model: CorrectionModel | FCNCorrectionModel, values: Mapping[str, Any]
                ) -> DepthStreamCorrector:
    """The stream corrector ``values`` (the node's parameters) describe, over ``model``
    (either kind; the fcn kind takes no edge or geodesic knob: :func:`ignored_parameters`).

    Raises:
        InputError: an invalid combination of the correction's knobs.
    """
    geodesic = (None if isinstance(model, FCNCorrectionModel)
                else effective_geodesic(model.geodesic, values))
    height, width = model.shape
    crop = (values["crop_width"] or width, values["crop_height"] or height)
    return DepthStreamCorrector(model, input_convention=values["input_convention"],
                                device=values["device"], threads=values["threads"],
                                geodesic=geodesic, crop=crop, precision=values["precision"],
                                fcn_engine=values["fcn_engine"])


def ignored_parameters(stream: DepthStreamCorrector, values: Mapping[str, Any]
                       ) -> dict[str, Any]:
    """The patch-only parameters set away from their defaults that ``stream`` ignores (its
    model is of the fcn kind), name -> value; empty for the patch kind."""
    if stream.geodesic is not None:
        return {}
    defaults = {p.name: p.default for p in PARAMETERS}
    return {name: values[name] for name in PATCH_ONLY_PARAMETERS
            if values[name] != defaults[name]}


def _warm_up(stream: DepthStreamCorrector, weights: str) -> float:
    """:meth:`DepthStreamCorrector.warm_up`, seconds; any failure becomes a TofMpdError."""
    try:
        return stream.warm_up()
    except Exception as err:
        raise TofMpdError(f"the model of {weights} does not run on device "
                          f"{stream.device!r}: {type(err).__name__}: {err}") from err


def _weights_text(values: Mapping[str, Any]) -> str:
    """The weights file ``values`` name (the shipped one for an empty weights_path)."""
    return values["weights_path"] or str(default_weights_path())


def _rebuilding(parameters: list[Parameter]) -> dict[str, Any]:
    """The parameters of a change that need a new correction, name -> new value."""
    return {p.name: p.value for p in parameters if p.name in REBUILD_PARAMETERS}


def _assignments(changes: Mapping[str, Any]) -> str:
    return ", ".join(f"{name}={value!r}" for name, value in changes.items())


def _describe(stream: DepthStreamCorrector, weights: str) -> str:
    """One line on the correction in use, for the log."""
    g = stream.geodesic
    knobs = (f"fcn kind, max sigma {stream.model.max_sigma_mm:g} mm, confidence = sigma in "
             "metres" if g is None else f"edges {g.edge_low:g}/{g.edge_high:g}, "
             f"geodesic K {g.k} sigma {g.sigma:g}")
    return (f"central {stream.crop_width}x{stream.crop_height} window, "
            f"{stream.input_convention} convention, {weights} on {stream.device}, "
            f"threads {stream.threads}, {knobs}")


def _fields(msg: Image) -> tuple[Any, ...]:
    """The decoding fields of an Image: encoding, height, width, step, is_bigendian, data."""
    return (msg.encoding, msg.height, msg.width, msg.step, bool(msg.is_bigendian), msg.data)


def _intrinsics(info: CameraInfo) -> Intrinsics:
    try:
        return intrinsics_of(info)
    except InputError as err:
        raise FrameRejected("bad_camera_info", f"CameraInfo is unusable: {err}") from err


def _stamp_text(ns: int) -> str:
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"
