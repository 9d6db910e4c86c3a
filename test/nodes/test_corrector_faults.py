"""Faults inside the corrector's worker (its own process, loopback only): after each, the node
corrects the next frames and ``/diagnostics`` counts what happened.

The node is ``faulty_corrector.py``: the real node, plus faults a frame can ask for by its
``frame_id`` (a failing publish, an exception in the pipeline, a slow frame). Each test first
makes the node log a warning drop, as a busy node does all the time: rclpy refuses a change of
severity at one logging call site, so a node that logs its warnings and its internal errors
from the same line dies at its first internal error after a warning.

Inputs are reliable (the node's ``input_reliability``), so every frame sent forms a pair and
the counters add up exactly.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from ros_harness import domain_id, start_node, stop_node  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402
from test_corrector_node import (  # noqa: E402
    DEEP,
    OUTPUT,
    SMALL,
    BadInputRig,
    listener,
    wait_for_corrector,
)

from tof_mpd_ros.calibration import IntrinsicCalibration  # noqa: E402
from tof_mpd_ros.correction.depth_stream import DROP_REASONS  # noqa: E402
from tof_mpd_ros.correction.pipeline import CorrectionModel  # noqa: E402
from tof_mpd_ros.correction.weights import save_weights  # noqa: E402
from tof_mpd_ros.nodes.ros_messages import (  # noqa: E402
    camera_info_message,
    image_message,
    stamp_ns,
)

DOMAIN = domain_id(8)
FAULTY_CORRECTOR = Path(__file__).with_name("faulty_corrector.py")
SLOW_S = 4.0  # faulty_corrector.SLOW_S
RELIABLE = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                      depth=1000)


class FaultRig(BadInputRig):
    """The bad-input rig's helpers, plus frames that carry a fault name as their frame_id."""

    def counters(self) -> dict[str, int]:
        """``published`` and every ``dropped_<reason>`` of the newest /diagnostics, once
        the node has reported everything sent so far (a few quiet periods)."""
        self.lis.spin_until(lambda: False, 1.0)
        values = self.lis.latest_values()
        keys = ["published", *(f"dropped_{r}" for r in DROP_REASONS)]
        return {k: int(values.get(k, "0")) for k in keys}

    def settle(self, before: dict[str, int], frames: int, timeout: float = 120.0
               ) -> dict[str, int]:
        """Wait until ``frames`` pairs sent since ``before`` are all accounted for (published
        or dropped); returns the counters' growth."""
        def growth() -> dict[str, int]:
            values = self.lis.latest_values()
            return {k: int(values.get(k, "0")) - v for k, v in before.items()}

        assert self.lis.spin_until(lambda: sum(growth().values()) >= frames, timeout), (
            growth(), self.log.read_text()[-3000:])
        self.lis.spin_until(lambda: False, 1.0)  # nothing more arrives late
        return {k: v for k, v in growth().items() if v}

    def warn_first(self) -> None:
        """Make the node log a warning drop (a bad encoding), as under everyday load."""
        before = self.counter("bad_encoding")
        depth_m, amplitude = self.frame()
        bad = image_message((depth_m * 1000).astype(np.uint16), "mono16")
        bad.encoding = "rgb16"
        self.publish(bad, image_message(amplitude, "32FC1"))
        self.expect_drop("bad_encoding", before)


def _send(rig: FaultRig, depth_m: np.ndarray, amplitude: np.ndarray,
          frame_id: str = "tof_optical_frame") -> int:
    """Publish one frame whose depth image carries ``frame_id``; returns its stamp."""
    t = rig.lis.node.get_clock().now().to_msg()
    info = camera_info_message(rig.intrinsics, "tof_optical_frame")
    info.header.stamp = t
    rig.info.publish(info)
    depth, amp = image_message(depth_m, "32FC1", frame_id), image_message(amplitude, "32FC1")
    for msg, pub in ((depth, rig.depth), (amp, rig.amplitude)):
        msg.header.stamp = t
        pub.publish(msg)
    return t.sec * 1_000_000_000 + t.nanosec


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[FaultRig]:
    out = tmp_path_factory.mktemp("faults")
    model = CorrectionModel.untrained(IntrinsicCalibration.identity(*SMALL), seed=3)
    log = out / "corrector.log"
    process = start_node("corrector", {"weights_path": str(save_weights(out / "small.npz", model)),
                                       "diagnostics_period_s": 0.25, "queue_size": 2,
                                       "input_reliability": "reliable", "input_depth": 1000},
                         DOMAIN, log, script=FAULTY_CORRECTOR, remap=["__ns:=/tof"])
    try:
        with listener(DOMAIN) as lis:
            node = lis.node
            outputs: dict[int, Image] = {}
            node.create_subscription(Image, OUTPUT, lambda m: outputs.__setitem__(stamp_ns(m), m),
                                     DEEP)
            r = FaultRig(lis, process, log,
                         node.create_publisher(Image, "/tof/depth/image_raw", RELIABLE),
                         node.create_publisher(Image, "/tof/amplitude/image_raw", RELIABLE),
                         node.create_publisher(CameraInfo, "/tof/depth/camera_info", RELIABLE),
                         outputs)
            wait_for_corrector(lis, process, log)
            assert lis.spin_until(lambda: all(p.get_subscription_count() >= 1
                                              for p in (r.depth, r.amplitude, r.info)), 120)
            r.expect_corrected()
            yield r
    finally:
        code = stop_node(process)
    assert code == 0, log.read_text()[-3000:]


def _fault_is_survived(rig: FaultRig, fault: str, message: str) -> None:
    """After a warning, a frame meeting ``fault`` is one internal error; frames go on."""
    rig.warn_first()
    rig.expect_corrected()
    before = rig.counters()
    _send(rig, *rig.frame(), frame_id=fault)
    grown = rig.settle(before, 1)
    assert grown == {"dropped_internal_error": 1}, grown
    values = rig.lis.latest_values()
    assert message in values["last_error"], values["last_error"]
    assert rig.lis.spin_until(lambda: "dropped (internal_error" in rig.log.read_text(), 30.0)
    for _ in range(3):  # the worker is alive: the next frames come out corrected
        rig.expect_corrected()
    assert "Traceback" not in rig.log.read_text()


def test_a_failing_publish_is_counted_and_the_next_frames_are_corrected(rig: FaultRig) -> None:
    _fault_is_survived(rig, "fault/publish", "injected publish fault")


def test_an_exception_inside_the_pipeline_is_counted_and_the_next_frames_are_corrected(
        rig: FaultRig) -> None:
    _fault_is_survived(rig, "fault/pipeline", "injected pipeline fault")


def test_queue_full_then_an_internal_error_the_worker_survives(rig: FaultRig) -> None:
    """The issue's sequence: the queue overflows behind a slow frame (a queue_full warning),
    then a frame raises inside the worker."""
    rig.expect_corrected()
    before = rig.counters()
    depth_m, amplitude = rig.frame()
    _send(rig, depth_m, amplitude, frame_id="fault/slow")
    rig.lis.spin_until(lambda: False, 0.3)  # the worker has taken it and sleeps SLOW_S
    for _ in range(5):  # 2 wait in the queue, 3 are dropped
        _send(rig, depth_m, amplitude)
    grown = rig.settle(before, 6)
    assert grown == {"published": 3, "dropped_queue_full": 3}, grown
    assert rig.lis.spin_until(lambda: "dropped (queue_full" in rig.log.read_text(), 30.0)
    before = rig.counters()
    time.sleep(0.1)
    _send(rig, depth_m, amplitude, frame_id="fault/pipeline")
    assert rig.settle(before, 1) == {"dropped_internal_error": 1}
    for _ in range(3):
        rig.expect_corrected()
    assert "Traceback" not in rig.log.read_text()


def storm_frames(shape: tuple[int, int], n: int, seed: int = 0
                 ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """``n`` (depth m, amplitude) frames of NaN, ±inf, zeros and negatives; in two of three, a
    few or half of the pixels are left valid, some of them absurd (1e30 m, 1e-30 m)."""
    rng = np.random.default_rng(seed)
    invalid = np.array([np.nan, np.inf, -np.inf, 0.0, -1.0], np.float32)
    for i in range(n):
        depth = rng.choice(invalid, shape).astype(np.float32)
        amplitude = rng.choice(invalid, shape).astype(np.float32)
        keep = rng.random(shape) < (0.0, 0.01, 0.5)[i % 3]
        depth[keep] = rng.choice([0.5, 1.0, 1e30, 1e-30], keep.sum(), p=[0.45, 0.45, 0.05, 0.05])
        amplitude[keep] = rng.uniform(10.0, 1000.0, keep.sum())
        yield depth, amplitude


def test_a_nan_storm_is_dropped_and_counted_then_frames_are_corrected(rig: FaultRig) -> None:
    rig.expect_corrected()
    n = 120
    before = rig.counters()
    for i, (depth_m, amplitude) in enumerate(storm_frames(rig.frame()[0].shape, n)):
        _send(rig, depth_m, amplitude)
        if i % 2:  # bursts of two: most reach the pipeline, some are shed
            rig.lis.spin_until(lambda: False, 0.02)
    grown = rig.settle(before, n)
    # every frame is accounted for once: corrected, rejected as invalid, or shed under load
    assert sum(grown.values()) == n, grown
    assert set(grown) <= {"published", "dropped_no_valid_pixel", "dropped_queue_full"}, grown
    assert grown.get("dropped_no_valid_pixel", 0) > 0 and grown.get("published", 0) > 0
    for _ in range(3):
        rig.expect_corrected()
    assert "Traceback" not in rig.log.read_text()
