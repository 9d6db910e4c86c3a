"""The corrector node class: a thin ROS shell over :class:`DepthStreamCorrector`.

Subscriptions only pair messages and queue them; a worker thread decodes, corrects and publishes
(bounded drop-oldest queue, every drop counted by reason and reported on ``/diagnostics``).
"""

from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image

from ..correction.default_weights import default_weights_path
from ..correction.depth_stream import DepthStreamCorrector
from ..correction.weights import load_weights
from ..errors import TofMpdError
from ..image_encoding import amplitude_to_float, depth_to_mm, image_to_array, mm_to_depth
from .pairing import LatestQueueWorker, StampPairer
from .parameters import ParameterSpec as P
from .parameters import declare
from .ros_messages import camera_info_message, image_message, intrinsics_of, stamp_ns

# The node's parameters; config/corrector.yaml mirrors these defaults (a test keeps them equal).
PARAMETERS = (
    P("weights_path", "", "Correction weights (.npz); empty = the weights shipped with the "
      "package.", read_only=True),
    P("depth_topic", "/tof/depth/image_raw", "Input depth image (32FC1 m, 16UC1 mm or "
      "64FC1 m).", read_only=True),
    P("amplitude_topic", "/tof/amplitude/image_raw", "Input amplitude image, same size.",
      read_only=True),
    P("camera_info_topic", "/tof/camera_info", "CameraInfo of the depth image.",
      read_only=True),
    P("output_topic", "/tof/depth_corrected/image", "Corrected depth; edges, confidence "
      "and camera_info are published beside it.", read_only=True),
    P("input_convention", "z", "z: input holds REP 118 z-depth; radial: radial ToF range. "
      "The output follows the input.", choices=("z", "radial"), read_only=True),
    P("output_encoding", "input", "Encoding of the corrected depth: input (same as the "
      "input), 32FC1 (metres) or 16UC1 (millimetres).",
      choices=("input", "32FC1", "16UC1")),
    P("device", "cpu", "Torch device for the networks (cpu, cuda, cuda:0...).",
      read_only=True),
    P("sync_tolerance_s", 0.005, "Largest stamp difference at which depth and amplitude "
      "pair.", min_value=0.0, max_value=1.0),
    P("queue_size", 2, "Pairs waiting for the worker; the oldest is dropped when full.",
      min_value=1, max_value=100, read_only=True),
    P("diagnostics_period_s", 1.0, "Period of /diagnostics messages.", min_value=0.05,
      max_value=60.0, read_only=True),
)


@dataclass
class _Pair:
    stamp_ns: int
    depth: object
    amplitude: object
    received: float


class CorrectorStats:
    """Thread-safe counters and latency history for diagnostics."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.published = 0
        self.drops: collections.Counter[str] = collections.Counter()
        self.latencies_ms: collections.deque[float] = collections.deque(maxlen=1000)
        self.last_error = ""
        self._stamps: collections.deque[float] = collections.deque(maxlen=100)

    def drop(self, reason: str, message: str = "") -> None:
        with self._lock:
            self.drops[reason] += 1
            if message:
                self.last_error = f"{reason}: {message}"

    def done(self, latency_ms: float) -> None:
        with self._lock:
            self.published += 1
            self.latencies_ms.append(latency_ms)
            self._stamps.append(time.monotonic())

    def snapshot(self) -> dict[str, str]:
        with self._lock:
            lat = np.array(self.latencies_ms) if self.latencies_ms else np.array([np.nan])
            span = self._stamps[-1] - self._stamps[0] if len(self._stamps) > 1 else 0.0
            rate = (len(self._stamps) - 1) / span if span > 0 else 0.0
            values = {"published": str(self.published), "rate_hz": f"{rate:.2f}",
                      "latency_p50_ms": f"{np.nanpercentile(lat, 50):.2f}",
                      "latency_p99_ms": f"{np.nanpercentile(lat, 99):.2f}",
                      "dropped_total": str(sum(self.drops.values())),
                      "last_error": self.last_error}
            values.update({f"dropped_{k}": str(v) for k, v in sorted(self.drops.items())})
            return values


class CorrectorNode(Node):
    def __init__(self) -> None:
        super().__init__("corrector")
        self.params = declare(self, PARAMETERS)
        weights = self.params["weights_path"] or str(default_weights_path())
        self.model = load_weights(Path(weights))  # WeightsError: refuse to start
        self.stream = DepthStreamCorrector(self.model,
                                           input_convention=self.params["input_convention"],
                                           device=self.params["device"])
        self.stats = CorrectorStats()
        self._camera_info: CameraInfo | None = None
        self._pair_lock = threading.Lock()
        self.pairer = StampPairer(int(self.params["sync_tolerance_s"] * 1e9))
        self.worker = LatestQueueWorker(self._process, maxsize=self.params["queue_size"],
                                        on_error=self._worker_error)
        out = self.params["output_topic"]
        base = out.rsplit("/", 1)[0] if "/" in out.strip("/") else ""
        qos = qos_profile_sensor_data
        self.pub_depth = self.create_publisher(Image, out, qos)
        self.pub_edges = self.create_publisher(Image, f"{base}/edges", qos)
        self.pub_confidence = self.create_publisher(Image, f"{base}/confidence", qos)
        self.pub_info = self.create_publisher(CameraInfo, f"{base}/camera_info", qos)
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(Image, self.params["depth_topic"], self._on_depth, qos)
        self.create_subscription(Image, self.params["amplitude_topic"], self._on_amplitude,
                                 qos)
        self.create_subscription(CameraInfo, self.params["camera_info_topic"],
                                 self._on_info, qos)
        self.create_timer(self.params["diagnostics_period_s"], self._publish_diagnostics)
        self.get_logger().info(f"correcting {self.params['depth_topic']} + "
                               f"{self.params['amplitude_topic']} -> {out} with {weights}")

    # -- callbacks: cheap, never block --------------------------------------------------
    def _on_info(self, msg: CameraInfo) -> None:
        self._camera_info = msg

    def _on_depth(self, msg: Image) -> None:
        self._pair(lambda p: p.add_left(stamp_ns(msg), msg))

    def _on_amplitude(self, msg: Image) -> None:
        self._pair(lambda p: p.add_right(stamp_ns(msg), msg))

    def _pair(self, add) -> None:
        with self._pair_lock:
            before = (self.pairer.stats.unmatched_dropped,
                      self.pairer.stats.out_of_order_dropped)
            pair = add(self.pairer)
            after = (self.pairer.stats.unmatched_dropped,
                     self.pairer.stats.out_of_order_dropped)
        if after[0] > before[0]:
            self.stats.drop("unpaired", "a depth or amplitude image found no partner "
                            "within sync_tolerance_s")
        if after[1] > before[1]:
            self.stats.drop("out_of_order", "stamp older than the last processed pair")
        if pair is not None:
            dropped_before = self.worker.dropped
            self.worker.submit(_Pair(pair[0], pair[1], pair[2], time.monotonic()))
            if self.worker.dropped > dropped_before:
                self.stats.drop("queue_full", "worker too slow, oldest pair dropped")

    # -- worker thread ------------------------------------------------------------------
    def _process(self, pair: _Pair) -> None:
        info = self._camera_info
        if info is None:
            self.stats.drop("no_camera_info", f"nothing on {self.params['camera_info_topic']}")
            return
        try:
            depth_msg, amp_msg = pair.depth, pair.amplitude
            depth = depth_to_mm(self._decode(depth_msg), depth_msg.encoding)
            amplitude = amplitude_to_float(self._decode(amp_msg))
            result = self.stream.correct(depth, amplitude, intrinsics_of(info))
        except TofMpdError as err:
            self.stats.drop("bad_input", str(err))
            self.get_logger().warning(f"frame dropped: {err}", throttle_duration_sec=5.0)
            return
        self._publish(pair, result, info)
        self.stats.done((time.monotonic() - pair.received) * 1e3)

    def _decode(self, msg: Image) -> np.ndarray:
        return image_to_array(msg.encoding, msg.height, msg.width, msg.step,
                              bool(msg.is_bigendian), msg.data)

    def _publish(self, pair: _Pair, result, info: CameraInfo) -> None:
        header = pair.depth.header
        encoding = self.params["output_encoding"]
        if encoding == "input":
            encoding = pair.depth.encoding if pair.depth.encoding != "mono16" else "16UC1"
        depth = mm_to_depth(result.depth_mm, encoding)
        self.pub_depth.publish(image_message(depth, encoding, header=header))
        edges = result.edges.astype(np.uint8) * 255
        self.pub_edges.publish(image_message(edges, "mono8", header=header))
        self.pub_confidence.publish(image_message(result.confidence, "32FC1", header=header))
        # The output is the processed crop: publish its intrinsics (distortion is not modelled).
        self.pub_info.publish(camera_info_message(result.intrinsics, header=header))

    def _worker_error(self, err: BaseException) -> None:
        self.stats.drop("internal_error", repr(err))
        self.get_logger().error(f"correction failed: {err!r}", throttle_duration_sec=5.0)

    def _publish_diagnostics(self) -> None:
        values = self.stats.snapshot()
        dropped = int(values["dropped_total"])
        level = DiagnosticStatus.OK if dropped == 0 else DiagnosticStatus.WARN
        if self.stats.published == 0 and dropped > 0:
            level = DiagnosticStatus.ERROR
        status = DiagnosticStatus(level=level, name="tof_mpd_ros: corrector",
                                  hardware_id=self.params["depth_topic"],
                                  message=values["last_error"] or "correcting")
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(msg)

    def destroy_node(self) -> None:
        self.worker.stop()
        super().destroy_node()

