"""The corrector node class: a thin ROS shell over :class:`DepthStreamCorrector`.

Subscriptions only pair messages and queue them; a worker thread decodes, corrects and publishes
(bounded drop-oldest queue, every drop counted by reason and reported on ``/diagnostics``).

Drop reasons are the keys of :data:`~tof_mpd_ros.correction.depth_stream.DROP_REASONS`. The
pairing stage (``no_amplitude``, ``no_depth``, ``out_of_order``) counts *images*; every later
stage counts depth/amplitude *pairs*.
"""

from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.exceptions import InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, Image

from ..camera import Intrinsics
from ..correction.default_weights import default_weights_path
from ..correction.depth_stream import (
    DROP_REASONS,
    DepthStreamCorrector,
    FrameRejected,
    StreamResult,
    decode_amplitude,
    decode_depth,
)
from ..correction.weights import load_weights
from ..errors import InputError, TofMpdError
from ..image_encoding import mm_to_depth
from .pairing import LatestQueueWorker, StampPairer, last_resort_report
from .parameters import ParameterSpec as P
from .parameters import declare, refuse_retired_parameters
from .qos import overridable_publisher, overridable_subscription, publisher_qos, subscription_qos
from .ros_messages import (
    cropped_camera_info,
    image_message,
    intrinsics_of,
    stamp_ns,
)

# The node's parameters; config/corrector.yaml mirrors these defaults (a test keeps them equal).
PARAMETERS = (
    P("weights_path", "", "Correction weights (.npz); empty = the weights shipped with the "
      "package.", read_only=True),
    P("input_convention", "z", "z: input holds REP 118 z-depth; radial: radial ToF range. "
      "The output follows the input.", choices=("z", "radial"), read_only=True),
    P("output_encoding", "input", "Encoding of the corrected depth: input (same as the "
      "input), 32FC1 (metres) or 16UC1 (millimetres).",
      choices=("input", "32FC1", "16UC1")),
    P("device", "cpu", "Torch device for the networks (cpu, cuda, cuda:0...).",
      read_only=True),
    # Aliases of the standard QoS overrides (docs/nodes.md): they set the profile that
    # qos_overrides.<topic>.* parameters default to, so old launch files keep working.
    P("input_reliability", "best_effort", "Alias: default reliability of the three input "
      "subscriptions (sensor-data QoS: best_effort); qos_overrides.<topic>.subscription."
      "reliability overrides it per topic.", choices=("best_effort", "reliable"),
      read_only=True),
    P("output_reliability", "reliable", "Alias: default reliability of the four outputs "
      "(reliable, like image_pipeline: default-QoS and sensor-data subscribers both match); "
      "qos_overrides.<topic>.publisher.reliability overrides it per topic.",
      choices=("best_effort", "reliable"), read_only=True),
    P("input_depth", 5, "Alias: default history depth of the three input subscriptions "
      "(sensor-data QoS: 5); qos_overrides.<topic>.subscription.depth overrides it per topic.",
      min_value=1, max_value=1000, read_only=True),
    P("threads", 1, "CPU threads for the networks (torch) and the geodesic filter (numba); "
      "0 = the libraries' default, one per core. One keeps 30 Hz at 180x140 on a 2-core "
      "machine and leaves the other cores to the rest of the robot's software.",
      min_value=0, max_value=256, read_only=True),
    P("sync_tolerance_s", 0.005, "Largest stamp difference at which depth and amplitude "
      "pair.", min_value=0.0, max_value=1.0),
    P("queue_size", 2, "Pairs waiting for the worker; the oldest is dropped when full.",
      min_value=1, max_value=100, read_only=True),
    P("diagnostics_period_s", 1.0, "Period of /diagnostics messages.", min_value=0.05,
      max_value=60.0, read_only=True),
)

# Topic names, relative like image_pipeline's: users move them with namespaces
# (``-r __ns:=/tof``) and remapping (``-r depth/image_raw:=/camera/depth``), not parameters.
TOPICS = {"depth": "depth/image_raw", "amplitude": "amplitude/image_raw",
          "camera_info": "depth/camera_info", "output": "depth_corrected/image",
          "edges": "depth_corrected/edges", "confidence": "depth_corrected/confidence",
          "output_camera_info": "depth_corrected/camera_info"}
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


class CorrectorNode(Node):
    """Subscribes to depth + amplitude + CameraInfo, publishes the corrected depth.

    Subscribes to ``depth/image_raw``, ``amplitude/image_raw`` and ``depth/camera_info``;
    publishes ``depth_corrected/image`` and beside it ``edges``
    (mono8, 255 = boundary from G), ``confidence`` (32FC1 in [0, 1]) and ``camera_info`` (the
    crop's), all with the input depth image's header; and ``/diagnostics``.

    Raises:
        WeightsError: the weights file is missing or unreadable.
        TofMpdError: a parameter is out of range, or the model does not run on ``device``.
        (The executable turns these into one line on stderr and exit code 2.)
    """

    def __init__(self) -> None:
        super().__init__("corrector")
        refuse_retired_parameters(self, RETIRED_TOPIC_PARAMETERS)
        try:
            self.params = declare(self, PARAMETERS)
        except (ValueError, InvalidParameterValueException) as err:
            raise InputError(f"bad parameter: {err}") from err
        weights = self.params["weights_path"] or str(default_weights_path())
        self.model = load_weights(Path(weights))  # WeightsError: refuse to start
        self.stream = DepthStreamCorrector(self.model,
                                           input_convention=self.params["input_convention"],
                                           device=self.params["device"],
                                           threads=self.params["threads"])
        try:  # JIT and thread pools now, not on the first frame; a bad device fails here
            warm_s = self.stream.warm_up()
        except Exception as err:
            raise TofMpdError(f"the model does not run on device {self.params['device']!r}: "
                              f"{type(err).__name__}: {err}") from err
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
            self._process, maxsize=self.params["queue_size"], on_error=self._worker_error)
        qos = publisher_qos(self.params["output_reliability"])
        in_qos = subscription_qos(self.params["input_reliability"], self.params["input_depth"])
        self.pub_depth = overridable_publisher(self, Image, TOPICS["output"], qos)
        self.pub_edges = overridable_publisher(self, Image, TOPICS["edges"], qos)
        self.pub_confidence = overridable_publisher(self, Image, TOPICS["confidence"], qos)
        self.pub_info = overridable_publisher(self, CameraInfo, TOPICS["output_camera_info"],
                                              qos)
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
        out = self.pub_depth.topic_name
        self.add_post_set_parameters_callback(self._on_parameters_set)
        self.create_timer(self.params["diagnostics_period_s"], self._publish_diagnostics)
        h, w = self.model.shape
        self.get_logger().info(
            f"correcting {self.topics['depth']} + {self.topics['amplitude']} -> "
            f"{out} (central {w}x{h} window, {self.params['input_convention']} convention) "
            f"with {weights}; warm-up frame {warm_s * 1e3:.0f} ms")

    # -- callbacks: cheap, never block --------------------------------------------------
    def _on_parameters_set(self, parameters: list[Parameter]) -> None:
        for p in parameters:
            if p.name in self.params:
                self.params[p.name] = p.value
            if p.name == "sync_tolerance_s":
                with self._pair_lock:
                    self.pairer.tolerance_ns = round(p.value * 1e9)

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
    def _process(self, pair: _Pair) -> None:
        info = self._camera_info
        if info is None and self._camera_info_ready.wait(CAMERA_INFO_WAIT_S):
            info = self._camera_info
        if info is None:
            self._drop("no_camera_info", "no CameraInfo on "
                       f"{self.topics['camera_info']} yet")
            return
        try:
            intrinsics = _intrinsics(info)
            depth = decode_depth(*_fields(pair.depth))
            amplitude = decode_amplitude(*_fields(pair.amplitude))
            result = self.stream.correct(depth, amplitude, intrinsics)
        except FrameRejected as err:
            self._drop(err.reason, str(err))
            return
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
        self.pub_edges.publish(image_message(edges, "mono8", header=header))
        self.pub_confidence.publish(image_message(result.confidence, "32FC1", header=header))
        self.pub_info.publish(cropped_camera_info(info, result.intrinsics, header=header))

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
