"""The corrector node in its own process (loopback only): a stream of simulated frames, bad
input, corrupt weights and a real Azure Kinect frame.

The weights are untrained (identity calibration, seeded networks): these tests check the node's
plumbing (pairing, decoding, conventions, queueing, publishing, diagnostics), not the method's
accuracy. They check behaviour, not speed: every wait is for a condition, with a timeout generous
enough for a machine shared with other busy processes, and no test counts on the node keeping up
with a rate. Speed (30 Hz with no dropped frame) is measured by
benchmarks/bench_corrector_node.py.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import signal
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import (  # noqa: E402
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from ros_harness import domain_id, spin_until, start_node, stop_node  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402

from tof_mpd_ros.calibration import IntrinsicCalibration  # noqa: E402
from tof_mpd_ros.camera import Intrinsics  # noqa: E402
from tof_mpd_ros.correction.depth_stream import (  # noqa: E402
    DROP_REASONS,
    DepthStreamCorrector,
    FrameRejected,
    decode_amplitude,
    decode_depth,
)
from tof_mpd_ros.correction.pipeline import CorrectionModel, central_window, correct  # noqa: E402
from tof_mpd_ros.correction.weights import load_weights, save_weights  # noqa: E402
from tof_mpd_ros.image_encoding import image_to_array  # noqa: E402
from tof_mpd_ros.nodes.ros_messages import (  # noqa: E402
    camera_info_message,
    image_message,
    intrinsics_of,
    stamp_ns,
)

STREAM_DOMAIN, BAD_INPUT_DOMAIN, REAL_DOMAIN, WEIGHTS_DOMAIN = (domain_id(k) for k in (2, 3, 4, 5))
QOS_DOMAIN = domain_id(11)  # also the remapping test's (one corrector at a time)
PAPER = (140, 180)  # (H, W) of the paper's crop: the stream test's model and frames
SMALL = (24, 32)  # (H, W) of the bad-input tests' model and frames
OUTPUT = "/tof/depth_corrected/image"
STREAM_FRAMES = 300  # frames the stream test sends (10 s of a 30 Hz camera)
IN_FLIGHT = 2  # frames sent ahead of the outputs received; also the node's queue_size there
DEPTH_OFFSETS_M = (0.0, 0.002, 0.005)  # added to each rendered view's depth: 6 distinct inputs
STALL_S = 120.0  # the stream test gives up when no output came back for this long
# sim_cell renders the stream test's views on topics of its own (the corrector does not see them).
SIM_TOPICS = {"depth": (Image, "/sim/depth/image_raw"),
              "amplitude": (Image, "/sim/amplitude/image_raw"),
              "info": (CameraInfo, "/sim/depth/camera_info")}
# sim_cell's (relative) names of those topics, remapped to SIM_TOPICS.
SIM_CELL_NAMES = {"depth": "tof/depth/image_raw", "amplitude": "tof/amplitude/image_raw",
                  "info": "tof/depth/camera_info"}
# Test subscribers: best effort (matches sensor-data publishers) with a deep history, so a
# busy test process does not lose what it is counting.
DEEP = QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST,
                  depth=1000)
RELIABLE_DEEP = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                           history=HistoryPolicy.KEEP_LAST, depth=1000)


# -- fixtures and helpers -------------------------------------------------------------------
@pytest.fixture(scope="session")
def weights(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Untrained models saved as weights files: the paper's 180x140 crop and a small one."""
    out = tmp_path_factory.mktemp("weights")
    paths = {}
    for name, (h, w) in (("paper", PAPER), ("small", SMALL)):
        model = CorrectionModel.untrained(IntrinsicCalibration.identity(h, w), seed=3)
        paths[name] = save_weights(out / f"{name}.npz", model)
    return paths


@dataclass
class Listener:
    """A node in the test process: a private rclpy context on ``domain_id``."""

    node: object
    executor: SingleThreadedExecutor
    diagnostics: list[DiagnosticArray] = field(default_factory=list)

    def spin_until(self, condition: Callable[[], bool], timeout: float) -> bool:
        return spin_until(self.node, self.executor, condition, timeout)

    def latest_values(self) -> dict[str, str]:
        """Key/values of the newest /diagnostics status from the corrector ({} if none)."""
        for msg in reversed(self.diagnostics):
            for status in msg.status:
                if status.name == "tof_mpd_ros: corrector":
                    return {kv.key: kv.value for kv in status.values}
        return {}

    def statuses(self) -> list:
        return [s for m in self.diagnostics for s in m.status
                if s.name == "tof_mpd_ros: corrector"]


@contextlib.contextmanager
def listener(domain_id: int) -> Iterator[Listener]:
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = rclpy.create_node(f"corrector_test_{domain_id}", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    lis = Listener(node, executor)
    node.create_subscription(DiagnosticArray, "/diagnostics", lis.diagnostics.append, 100)
    try:
        yield lis
    finally:
        executor.shutdown()
        node.destroy_node()
        context.try_shutdown()


def start_corrector(weights_path: Path, domain_id: int, log: Path,
                    remap: tuple[str, ...] = ("__ns:=/tof",), **params: object):
    """The corrector in namespace /tof (its topics are relative), as the launch files start it."""
    return start_node("corrector", {"weights_path": str(weights_path),
                                    "diagnostics_period_s": 0.25, **params}, domain_id, log,
                      remap=remap)


def wait_for_corrector(lis: Listener, process, log: Path, timeout: float = 300.0) -> None:
    """Until the corrector process publishes /diagnostics (it is up and spinning)."""
    ok = lis.spin_until(lambda: bool(lis.latest_values()) or process.poll() is not None,
                        timeout)
    assert ok and process.poll() is None, log.read_text()[-3000:]


def node_count(lis: Listener, key: str) -> int:
    """A counter of the corrector's newest /diagnostics (0 before the first)."""
    return int(lis.latest_values().get(key, "0"))


def first_round_trip(lis: Listener, publishers: list, messages: tuple,
                     came_back: Callable[[int], bool], process, log: Path,
                     timeout: float = 300.0) -> list[int]:
    """Send ``messages`` (depth, amplitude, CameraInfo), freshly stamped, until
    ``came_back(stamp)``; returns the stamps sent, in order.

    CameraInfo goes alone first, until the node reports it (a pair that arrives before any
    CameraInfo waits for it only a second). Then frames one at a time, the next only once the node
    has published the previous one, so that its queue never holds two, until one comes back: an
    output the node publishes before its publisher has found this process's subscription is not
    delivered, and DDS discovery takes its time on a busy machine.
    """
    deadline = time.monotonic() + timeout

    def check() -> None:
        assert time.monotonic() < deadline and process.poll() is None, (
            f"nothing came back; {lis.latest_values()}; log:\n{log.read_text()[-3000:]}")

    while node_count(lis, "received_camera_info") < 1:
        check()
        send(publishers, (None, None, messages[2]), time.time_ns())
        lis.spin_until(lambda: node_count(lis, "received_camera_info") >= 1, 0.5)
    sent: list[int] = []
    while not any(came_back(t) for t in sent):
        check()
        if node_count(lis, "published") >= len(sent):
            sent.append(time.time_ns())
            send(publishers, messages, sent[-1])
        lis.spin_until(lambda: False, 0.1)
    return sent


def send(publishers: list, messages: tuple, stamp: int) -> None:
    """Publish a (depth, amplitude, CameraInfo) triple (None: not that one), all stamped
    ``stamp`` (ns); CameraInfo first, as a camera driver does."""
    from builtin_interfaces.msg import Time

    t = Time(sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000)
    for i in (2, 0, 1):
        if messages[i] is not None:
            messages[i].header.stamp = t
            publishers[i].publish(messages[i])


def offline_output(model: CorrectionModel, depth: Image, amplitude: Image,
                   info: CameraInfo) -> np.ndarray:
    """The corrected depth in mm the node should publish for this input (z convention)."""
    stream = DepthStreamCorrector(model, input_convention="z")
    result = stream.correct(decode_depth(*fields(depth)), decode_amplitude(*fields(amplitude)),
                            intrinsics_of(info))
    return result.depth_mm


def fields(msg: Image) -> tuple:
    return (msg.encoding, msg.height, msg.width, msg.step, bool(msg.is_bigendian), msg.data)


def decoded(msg: Image) -> np.ndarray:
    return image_to_array(msg.encoding, msg.height, msg.width, msg.step,
                          bool(msg.is_bigendian), msg.data)


# -- 1. a stream of simulated frames, every one corrected ------------------------------------
def rendered_views(lis: Listener, sim, log: Path, n_views: int
                   ) -> list[tuple[Image, Image, CameraInfo]]:
    """(depth, amplitude, CameraInfo) of each of the ``n_views`` views sim_cell cycles through
    on SIM_TOPICS (one stamp each, distinct depth images)."""
    got: dict[str, dict[int, object]] = {key: {} for key in SIM_TOPICS}
    for key, (kind, topic) in SIM_TOPICS.items():
        lis.node.create_subscription(kind, topic,
                                     lambda m, k=key: got[k].__setitem__(stamp_ns(m), m),
                                     RELIABLE_DEEP)

    def views() -> dict[bytes, int]:
        """Depth payload -> the first stamp that has all three messages."""
        first: dict[bytes, int] = {}
        for stamp in sorted(got["depth"]):
            if stamp in got["amplitude"] and stamp in got["info"]:
                first.setdefault(bytes(got["depth"][stamp].data), stamp)
        return first

    # Rendering takes a few seconds idle, minutes on a loaded machine: wait for it, not a clock.
    assert lis.spin_until(lambda: len(views()) >= n_views or sim.poll() is not None, 500.0), \
        log.read_text()[-3000:]
    assert sim.poll() is None, log.read_text()[-3000:]
    return [(got["depth"][t], got["amplitude"][t], got["info"][t])
            for t in sorted(views().values())[:n_views]]


def frame_variants(views: list[tuple[Image, Image, CameraInfo]]
                   ) -> list[tuple[Image, Image, CameraInfo]]:
    """Each view with each of DEPTH_OFFSETS_M added to its depth (NaN stays NaN): the inputs
    the stream test cycles through, so that neighbouring frames differ."""
    out = []
    for depth, amplitude, info in views:
        for offset in DEPTH_OFFSETS_M:
            depth_m = decoded(depth) + np.float32(offset)
            out.append((image_message(depth_m, depth.encoding, depth.header.frame_id),
                        image_message(decoded(amplitude), amplitude.encoding,
                                      amplitude.header.frame_id), info))
    return out


@pytest.mark.parametrize("parallel_frames", [1, 2])
def test_every_frame_sent_comes_back_corrected_like_the_offline_pipeline(
        weights: dict[str, Path], tmp_path: Path, parallel_frames: int) -> None:
    """This process -> corrector -> this process: STREAM_FRAMES frames at the paper's 180x140
    crop, each comes back once, equal to the offline pipeline, to a default-QoS subscriber
    (``create_subscription(..., 10)``: reliable, what RViz2 and most user code use) and to a
    sensor-data one alike, with the node's default output QoS.

    sim_cell renders two views; this process sends frames made from them (three depth offsets
    per view, so that neighbouring frames differ), stamped like a 30 Hz camera, but never more
    than IN_FLIGHT ahead of the corrected outputs it has received back. The node runs with
    ``queue_size`` IN_FLIGHT, so its drop-oldest queue never has to drop, however slow or busy
    the machine, and the inputs are reliable (DDS does not lose a frame on a busy host). So the
    node must publish every frame, exactly once, with its header, equal to
    ``DepthStreamCorrector`` run offline on the same input, and count no drop. Whether it keeps
    up with 30 Hz is measured by benchmarks/bench_corrector_node.py, not here. With
    ``parallel_frames`` 2 the two frames in flight are corrected at once, and the outputs must
    still come back in the order the frames were sent.
    """
    h, w = PAPER
    corrector_log, sim_log = tmp_path / "corrector.log", tmp_path / "sim_cell.log"
    corrector = start_corrector(weights["paper"], STREAM_DOMAIN, corrector_log,
                                queue_size=IN_FLIGHT, input_reliability="reliable",
                                parallel_frames=parallel_frames)
    sim = start_node("sim_cell", {"views": 2, "crop_width": w, "crop_height": h,
                                  "publish_reference": False},
                     STREAM_DOMAIN, sim_log,
                     remap=[f"{SIM_CELL_NAMES[k]}:={SIM_TOPICS[k][1]}" for k in SIM_TOPICS])
    returned: dict[int, list[Image]] = {}  # default-QoS subscriber
    returned_sensor: dict[int, list[Image]] = {}  # sensor-data subscriber
    try:
        with listener(STREAM_DOMAIN) as lis:
            node = lis.node
            inputs = frame_variants(rendered_views(lis, sim, sim_log, 2))
            assert stop_node(sim) == 0, sim_log.read_text()[-3000:]
            node.create_subscription(
                Image, OUTPUT, lambda m: returned.setdefault(stamp_ns(m), []).append(m), 10)
            node.create_subscription(
                Image, OUTPUT, lambda m: returned_sensor.setdefault(stamp_ns(m), []).append(m),
                qos_profile_sensor_data)
            pubs = [node.create_publisher(kind, topic, RELIABLE_DEEP) for kind, topic in
                    ((Image, "/tof/depth/image_raw"), (Image, "/tof/amplitude/image_raw"),
                     (CameraInfo, "/tof/depth/camera_info"))]
            wait_for_corrector(lis, corrector, corrector_log)
            assert lis.spin_until(lambda: all(p.get_subscription_count() >= 1 for p in pubs),
                                  120.0)
            # Warm-up: until a frame has made the round trip (discovery is done both ways).
            warm = first_round_trip(lis, pubs, inputs[0],
                                    lambda t: t in returned and t in returned_sensor,
                                    corrector, corrector_log)

            # The stream: frame i is input i % 6, stamped 1/30 s after frame i - 1.
            t0 = time.time_ns()
            stamps = [t0 + round(i * 1e9 / 30.0) for i in range(STREAM_FRAMES)]
            which = {stamp: i % len(inputs) for i, stamp in enumerate(stamps)}
            n_sent, n_back, last_progress = 0, 0, time.monotonic()
            while n_back < STREAM_FRAMES:
                if n_sent < STREAM_FRAMES and n_sent - n_back < IN_FLIGHT:
                    send(pubs, inputs[which[stamps[n_sent]]], stamps[n_sent])
                    n_sent += 1
                    continue
                lis.executor.spin_once(timeout_sec=0.05)
                # Paced by both subscribers: neither history (10, 5) can overflow.
                now_back = sum(1 for t in stamps[:n_sent]
                               if t in returned and t in returned_sensor)
                if now_back > n_back:
                    n_back, last_progress = now_back, time.monotonic()
                elif time.monotonic() - last_progress > STALL_S or corrector.poll() is not None:
                    break  # the node lost a frame (or died): report below
            # The node's counters after its last frame (two diagnostics periods).
            total = len(warm) + STREAM_FRAMES
            lis.spin_until(lambda: node_count(lis, "published") >= total, 60.0)
            n_diag = len(lis.diagnostics)
            lis.spin_until(lambda: len(lis.diagnostics) >= n_diag + 2, 60.0)
            values = lis.latest_values()
        assert corrector.poll() is None, "the corrector exited"
    finally:
        stop_node(sim)
        code = stop_node(corrector)
    log = corrector_log.read_text()
    assert code == 0, log[-3000:]

    # Every frame sent came back, once; the node dropped nothing and published each pair once.
    lost = [i for i, t in enumerate(stamps) if t not in returned]
    assert not lost, (f"{len(lost)} of {STREAM_FRAMES} frames without output (frames "
                      f"{lost[:10]}...; {n_sent} sent); diagnostics {values}; log:\n{log[-3000:]}")
    assert all(len(returned[t]) == 1 for t in stamps), "a frame came back twice"
    arrived = [t for t in returned if t in which]   # a dict keeps the order of arrival
    assert arrived == sorted(arrived), "outputs published out of the order sent"
    lost_sensor = [i for i, t in enumerate(stamps) if t not in returned_sensor]
    assert not lost_sensor, f"the sensor-data subscriber missed frames {lost_sensor[:10]}..."
    assert all(returned_sensor[t][0].data == returned[t][0].data for t in stamps)
    assert set(returned) <= set(stamps) | set(warm), "an output with a stamp never sent"
    assert values["dropped_total"] == "0", str({k: v for k, v in values.items() if v != "0"})
    assert int(values["published"]) == int(values["received_depth"]) == \
        int(values["received_amplitude"]) == total, values

    # The published range equals the offline pipeline on the same input.
    model = load_weights(weights["paper"])
    expected: dict[int, np.ndarray] = {}
    for stamp in stamps:
        out, k = returned[stamp][0], which[stamp]
        depth, amplitude, info = inputs[k]
        if k not in expected:
            expected[k] = offline_output(model, depth, amplitude, info)
        assert (out.encoding, out.height, out.width) == ("32FC1", h, w)
        assert out.header.frame_id == depth.header.frame_id
        got_mm = decoded(out).astype(np.float64) * 1000.0
        np.testing.assert_array_equal(np.isnan(got_mm), np.isnan(expected[k]))
        np.testing.assert_allclose(got_mm, expected[k], rtol=0, atol=1e-3, equal_nan=True)
    assert len(expected) == len(inputs) == 6
    # Different inputs give different outputs: each frame really was its own input's.
    assert len({bytes(returned[t][0].data) for t in stamps}) == len(inputs)
    assert "Traceback" not in log


def test_qos_overrides_parameters_set_the_reliability_of_one_topic(weights: dict[str, Path],
                                                                    tmp_path: Path) -> None:
    """The standard ``qos_overrides.<topic>.<publisher|subscription>.reliability`` parameters
    change that one topic's QoS, as another node sees it; the other topics keep the defaults
    (reliable outputs, best-effort inputs)."""
    from rclpy.qos import QoSReliabilityPolicy

    log = tmp_path / "corrector.log"
    process = start_corrector(weights["small"], QOS_DOMAIN, log, **{
        f"qos_overrides.{OUTPUT}.publisher.reliability": "best_effort",
        "qos_overrides./tof/depth/image_raw.subscription.reliability": "reliable"})
    try:
        with listener(QOS_DOMAIN) as lis:
            wait_for_corrector(lis, process, log)

            def reliability(topic: str, publisher: bool) -> list:
                info = (lis.node.get_publishers_info_by_topic(topic) if publisher
                        else lis.node.get_subscriptions_info_by_topic(topic))
                return [i.qos_profile.reliability for i in info if i.node_name == "corrector"]

            edges = OUTPUT.rsplit("/", 1)[0] + "/edges"
            assert lis.spin_until(lambda: all(
                reliability(t, pub) for t, pub in ((OUTPUT, True), (edges, True),
                                                   ("/tof/depth/image_raw", False),
                                                   ("/tof/amplitude/image_raw", False))), 60.0)
            assert reliability(OUTPUT, True) == [QoSReliabilityPolicy.BEST_EFFORT]
            assert reliability(edges, True) == [QoSReliabilityPolicy.RELIABLE]
            assert reliability("/tof/depth/image_raw", False) == [QoSReliabilityPolicy.RELIABLE]
            assert reliability("/tof/amplitude/image_raw", False) == [
                QoSReliabilityPolicy.BEST_EFFORT]
    finally:
        code = stop_node(process)
    assert code == 0, log.read_text()[-3000:]


def test_a_namespace_and_a_remapped_input_move_the_topics(weights: dict[str, Path],
                                                          tmp_path: Path) -> None:
    """``-r __ns:=/cam -r amplitude/image_raw:=/ir/image``: the node reads /cam/depth/image_raw,
    /ir/image and /cam/depth/camera_info and publishes /cam/depth_corrected/*, and nothing on
    its default names."""
    log = tmp_path / "corrector.log"
    process = start_corrector(weights["small"], QOS_DOMAIN, log,
                              remap=("__ns:=/cam", "amplitude/image_raw:=/ir/image"))
    h, w = SMALL
    try:
        with listener(QOS_DOMAIN) as lis:
            node, qos = lis.node, qos_profile_sensor_data
            got: dict[str, list[int]] = {"image": [], "camera_info": [], "old": []}
            node.create_subscription(Image, "/cam/depth_corrected/image",
                                     lambda m: got["image"].append(stamp_ns(m)), DEEP)
            node.create_subscription(CameraInfo, "/cam/depth_corrected/camera_info",
                                     lambda m: got["camera_info"].append(stamp_ns(m)), DEEP)
            node.create_subscription(Image, OUTPUT, lambda m: got["old"].append(1), DEEP)
            pubs = [node.create_publisher(Image, "/cam/depth/image_raw", qos),
                    node.create_publisher(Image, "/ir/image", qos),
                    node.create_publisher(CameraInfo, "/cam/depth/camera_info", qos)]
            wait_for_corrector(lis, process, log)
            assert lis.spin_until(lambda: all(p.get_subscription_count() >= 1 for p in pubs),
                                  120.0), node.get_topic_names_and_types()
            u = np.mgrid[0:h, 0:w][1]
            messages = (image_message((0.3 + 0.0005 * u).astype(np.float32), "32FC1"),
                        image_message((500.0 + 2.0 * u).astype(np.float32), "32FC1"),
                        camera_info_message(Intrinsics.from_fov(w, h, 60.0), ""))
            sent = first_round_trip(lis, pubs, messages, lambda t: t in got["image"], process,
                                    log)
            assert lis.spin_until(lambda: sent[-1] in got["camera_info"], 60.0)
            names = dict(node.get_topic_names_and_types())
            assert "/cam/depth_corrected/edges" in names and "/cam/depth_corrected/confidence" \
                in names
            assert got["old"] == [] and not node.get_publishers_info_by_topic(OUTPUT)
            assert not any(n.startswith("/tof/") for n in names if n != OUTPUT), names
    finally:
        code = stop_node(process)
    assert code == 0, log.read_text()[-3000:]


@pytest.mark.parametrize("retired", ["depth_topic", "output_topic"])
def test_a_retired_topic_parameter_stops_the_node_naming_the_remapping(
        weights: dict[str, Path], tmp_path: Path, retired: str) -> None:
    log = tmp_path / "corrector.log"
    process = start_corrector(weights["small"], WEIGHTS_DOMAIN, log, **{retired: "/x/y"})
    try:
        code = process.wait(300)
    finally:
        stop_node(process)
    lines = [line for line in log.read_text().splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, lines
    assert lines[0].startswith("corrector: cannot start:") and retired in lines[0]
    assert ":=/x/y" in lines[0] and "-r " in lines[0], lines


# -- 2. bad input: logged, counted, reported; the node keeps running -------------------------
@dataclass
class BadInputRig:
    """One corrector process and a publisher of hand-made frames, shared by the tests."""

    lis: Listener
    process: object
    log: Path
    depth: object
    amplitude: object
    info: object
    outputs: dict[int, Image]
    intrinsics: Intrinsics = field(default_factory=lambda: Intrinsics.from_fov(
        SMALL[1], SMALL[0], 60.0))

    def frame(self) -> tuple[np.ndarray, np.ndarray]:
        """A valid (H, W) z-depth (m, a tilted plane) and amplitude pair."""
        h, w = SMALL
        v, u = np.mgrid[0:h, 0:w]
        depth_m = (0.3 + 0.0005 * u + 0.0002 * v).astype(np.float32)
        amplitude = (500.0 + 2.0 * u).astype(np.float32)
        return depth_m, amplitude

    def publish(self, depth: Image | None, amplitude: Image | None,
                stamp_s: float | None = None, info: CameraInfo | None = None) -> int:
        """Publish with one stamp (default: now); returns it in nanoseconds."""
        t = (self.lis.node.get_clock().now().to_msg() if stamp_s is None
             else _time_msg(stamp_s))
        info = info or camera_info_message(self.intrinsics, "tof_optical_frame")
        info.header.stamp = t
        self.info.publish(info)
        for msg, pub in ((depth, self.depth), (amplitude, self.amplitude)):
            if msg is not None:
                msg.header.stamp = t
                msg.header.frame_id = "tof_optical_frame"
                pub.publish(msg)
        return t.sec * 1_000_000_000 + t.nanosec

    def publish_good(self, stamp_s: float | None = None) -> int:
        depth_m, amplitude = self.frame()
        return self.publish(image_message(depth_m, "32FC1"),
                            image_message(amplitude, "32FC1"), stamp_s)

    def expect_corrected(self, timeout: float = 120.0) -> None:
        """A good frame still comes out (retried: sensor-data QoS is best effort)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            stamp = self.publish_good()
            if self.lis.spin_until(lambda s=stamp: s in self.outputs, 5.0):
                break
        else:
            pytest.fail(f"no corrected output; log:\n{self.log.read_text()[-3000:]}")
        assert self.process.poll() is None

    def counter(self, reason: str) -> int:
        return int(self.lis.latest_values().get(f"dropped_{reason}", "0"))

    def expect_drop(self, reason: str, before: int, timeout: float = 60.0) -> dict[str, str]:
        """The counter for ``reason`` grows, a /diagnostics message names it, the log too.

        The message to look at is that of the period in which the counter grew (a status
        names the reasons dropped since the previous one), however long ago that was.
        """
        assert self.lis.spin_until(lambda: self.counter(reason) > before, timeout), (
            self.lis.latest_values(), self.log.read_text()[-3000:])

        def named() -> bool:
            for status in self.lis.statuses():
                values = {kv.key: kv.value for kv in status.values}
                if int(values.get(f"dropped_{reason}", "0")) > before:
                    return reason in status.message
            return False

        assert self.lis.spin_until(named, 30.0), [s.message for s in self.lis.statuses()[-5:]]
        assert self.lis.spin_until(lambda: f"dropped ({reason}" in self.log.read_text(), 30.0), \
            self.log.read_text()[-3000:]
        return self.lis.latest_values()


def _time_msg(seconds: float):
    from builtin_interfaces.msg import Time

    ns = round(seconds * 1e9)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


@pytest.fixture(scope="module")
def rig(weights: dict[str, Path], tmp_path_factory: pytest.TempPathFactory
        ) -> Iterator[BadInputRig]:
    log = tmp_path_factory.mktemp("bad_input") / "corrector.log"
    process = start_corrector(weights["small"], BAD_INPUT_DOMAIN, log)
    try:
        with listener(BAD_INPUT_DOMAIN) as lis:
            node = lis.node
            outputs: dict[int, Image] = {}
            node.create_subscription(Image, OUTPUT, lambda m: outputs.__setitem__(stamp_ns(m), m),
                                     DEEP)
            qos = qos_profile_sensor_data
            r = BadInputRig(lis, process, log,
                            node.create_publisher(Image, "/tof/depth/image_raw", qos),
                            node.create_publisher(Image, "/tof/amplitude/image_raw", qos),
                            node.create_publisher(CameraInfo, "/tof/depth/camera_info", qos),
                            outputs)
            wait_for_corrector(lis, process, log)
            assert lis.spin_until(lambda: all(p.get_subscription_count() >= 1
                                              for p in (r.depth, r.amplitude, r.info)), 120)
            r.expect_corrected()
            yield r
            assert process.poll() is None, "the corrector exited"
    finally:
        code = stop_node(process)
    assert code == 0, log.read_text()[-3000:]
    assert "Traceback" not in log.read_text()


def test_wrong_depth_encoding_is_dropped_and_reported(rig: BadInputRig) -> None:
    before = rig.counter("bad_encoding")
    depth_m, amplitude = rig.frame()
    rgb = np.repeat((depth_m * 100).astype(np.uint8)[..., None], 3, axis=2)
    bad = Image(height=rgb.shape[0], width=rgb.shape[1], encoding="rgb8", is_bigendian=0,
                step=rgb.shape[1] * 3, data=rgb.tobytes())
    rig.publish(bad, image_message(amplitude, "32FC1"))
    values = rig.expect_drop("bad_encoding", before)
    assert "rgb8" in values["last_error"] and "REP 118" in values["last_error"]
    rig.expect_corrected()


def test_depth_and_amplitude_of_different_sizes_are_dropped(rig: BadInputRig) -> None:
    before = rig.counter("size_mismatch")
    depth_m, amplitude = rig.frame()
    rig.publish(image_message(depth_m, "32FC1"), image_message(amplitude[::2, ::2], "32FC1"))
    values = rig.expect_drop("size_mismatch", before)
    assert "32x24" in values["last_error"] and "16x12" in values["last_error"]
    rig.expect_corrected()


def test_an_all_nan_frame_is_dropped(rig: BadInputRig) -> None:
    before = rig.counter("no_valid_pixel")
    depth_m, amplitude = rig.frame()
    rig.publish(image_message(np.full_like(depth_m, np.nan), "32FC1"),
                image_message(amplitude, "32FC1"))
    rig.expect_drop("no_valid_pixel", before)
    rig.expect_corrected()


def test_out_of_order_stamps_are_dropped(rig: BadInputRig) -> None:
    rig.expect_corrected()
    before = rig.counter("out_of_order")
    n_out = len(rig.outputs)
    old = time.time() - 10.0
    rig.publish(*(image_message(a, "32FC1") for a in rig.frame()), stamp_s=old)
    rig.expect_drop("out_of_order", before)
    assert len(rig.outputs) == n_out  # nothing was published for the old stamp
    rig.expect_corrected()


def test_a_jump_back_in_time_restarts_pairing(rig: BadInputRig) -> None:
    """A recording replayed from its start: a few frames are out of order, then it pairs."""
    rig.expect_corrected()
    before = rig.counter("out_of_order")
    t0 = time.time() - 100.0
    stamps = []
    for i in range(12):
        stamps.append(rig.publish(*(image_message(a, "32FC1") for a in rig.frame()),
                                  stamp_s=t0 + i / 30.0))
        rig.lis.spin_until(lambda: False, 0.05)
    assert rig.lis.spin_until(lambda: stamps[-1] in rig.outputs, 60.0), (
        rig.lis.latest_values(), rig.log.read_text()[-2000:])
    values = rig.expect_drop("out_of_order", before)
    assert int(values["pairing_resets"]) >= 1
    assert "pairing restarted" in rig.log.read_text()
    rig.expect_corrected()


def test_amplitude_never_arriving_is_counted_and_reported(rig: BadInputRig) -> None:
    before = rig.counter("no_amplitude")
    depth_m, _ = rig.frame()
    n_status = len(rig.lis.statuses())

    def missing() -> list:
        return [s for s in rig.lis.statuses()[n_status:]
                if "nothing on /tof/amplitude/image_raw" in s.message
                or "no amplitude was ever received" in s.message]

    # Depth only, at 10 Hz, until the node has dropped several for want of a partner (the pairer
    # keeps 8 waiting) and /diagnostics has named the silent stream: at least 15 images.
    deadline = time.monotonic() + 120.0
    for i in itertools.count():
        rig.publish(image_message(depth_m, "32FC1"), None)
        rig.lis.spin_until(lambda: False, 0.1)
        if i >= 15 and rig.counter("no_amplitude") >= before + 5 and missing():
            break
        assert time.monotonic() < deadline, (rig.lis.latest_values(),
                                             [s.message for s in rig.lis.statuses()[-5:]])
    values = rig.expect_drop("no_amplitude", before)
    assert int(values["dropped_no_amplitude"]) >= before + 5
    assert missing(), [s.message for s in rig.lis.statuses()[-5:]]
    assert missing()[-1].level == DiagnosticStatus.ERROR
    rig.expect_corrected()


def test_diagnostics_report_every_reason_key_and_recover_to_ok(rig: BadInputRig) -> None:
    rig.expect_corrected()
    values = rig.lis.latest_values()
    assert {f"dropped_{r}" for r in DROP_REASONS} <= set(values)
    for key in ("published", "rate_hz", "latency_p50_ms", "latency_p99_ms", "last_error",
                "received_depth", "amplitude_age_s"):
        assert key in values
    for _ in range(8):  # a clean stream for a few periods -> level OK again
        rig.publish_good()
        rig.lis.spin_until(lambda: False, 0.15)
    assert rig.lis.spin_until(lambda: rig.lis.statuses()[-1].level == DiagnosticStatus.OK,
                              60.0), \
        [s.message for s in rig.lis.statuses()[-3:]]


def test_output_encoding_can_be_changed_while_running(rig: BadInputRig) -> None:
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    client = AsyncParameterClient(rig.lis.node, "/tof/corrector")  # its namespace: /tof
    assert client.wait_for_services(timeout_sec=120.0)

    def set_encoding(value: str):
        future = client.set_parameters([Parameter("output_encoding", value=value)])
        assert rig.lis.spin_until(future.done, 60.0)
        return future.result().results[0]

    assert not set_encoding("rgb8").successful  # refused with a reason
    assert set_encoding("16UC1").successful
    try:
        rig.expect_corrected()
        latest = rig.outputs[max(rig.outputs)]
        assert latest.encoding == "16UC1"
        depth_m, _ = rig.frame()
        np.testing.assert_allclose(decoded(latest), depth_m * 1000.0, atol=30.0)
    finally:
        assert set_encoding("input").successful
    rig.expect_corrected()
    assert rig.outputs[max(rig.outputs)].encoding == "32FC1"


# -- 3. weights that cannot be loaded: refuse to start, one clear line ------------------------
@pytest.mark.parametrize("damage", ["garbage", "truncated", "missing"])
def test_unloadable_weights_stop_the_node_with_one_clear_line(
        weights: dict[str, Path], tmp_path: Path, damage: str) -> None:
    bad = tmp_path / "bad.npz"
    if damage == "garbage":
        bad.write_bytes(b"\x93NUMPY this is not a weights file" * 10)
    elif damage == "truncated":
        data = weights["small"].read_bytes()
        bad.write_bytes(data[: len(data) // 2])
    log = tmp_path / "corrector.log"
    process = start_corrector(bad, WEIGHTS_DOMAIN, log)
    try:
        code = process.wait(300)
    finally:
        stop_node(process)
    lines = [line for line in log.read_text().splitlines() if line.strip()]
    assert code != 0
    assert len(lines) == 1, lines
    assert lines[0].startswith("corrector: cannot start:") and str(bad) in lines[0], lines


@pytest.mark.parametrize("param", [{"queue_size": 0}, {"input_convention": "zz"},
                                   {"device": "cuda:7"}])
def test_bad_parameters_stop_the_node_with_one_clear_line(
        weights: dict[str, Path], tmp_path: Path, param: dict[str, object]) -> None:
    log = tmp_path / "corrector.log"
    process = start_corrector(weights["small"], WEIGHTS_DOMAIN, log, **param)
    try:
        code = process.wait(300)
    finally:
        stop_node(process)
    lines = [line for line in log.read_text().splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, lines
    assert lines[0].startswith("corrector: cannot start:") and next(iter(param)) in lines[0]


# -- 4. a real Azure Kinect frame -----------------------------------------------------------
def azure_kinect_nfov_unbinned_camera_info(calibration_json: Path) -> CameraInfo:
    """CameraInfo of the 640x576 NFOV-unbinned depth image from the factory calibration.

    ``ModelParameters`` (cx, cy, fx, fy, k1..k6, codx, cody, p2, p1) are normalised by the
    1024x1024 calibration image (``SensorWidth`` x ``SensorHeight``) with (0, 0) at the corner of
    the top-left pixel. The Azure Kinect SDK's NFOV-unbinned mode crops that image at offset
    (192, 180) to 640x576 and shifts to pixel-centred coordinates (-0.5): see
    ``transformation_get_mode_specific_depth_camera_calibration`` in the SDK.
    """
    cal = json.loads(calibration_json.read_text())["CalibrationInformation"]["Cameras"]
    depth = next(c for c in cal if c["Purpose"] == "CALIBRATION_CameraPurposeDepth")
    p = depth["Intrinsics"]["ModelParameters"]
    sw, sh = depth["SensorWidth"], depth["SensorHeight"]
    cx, cy = p[0] * sw - 192 - 0.5, p[1] * sh - 180 - 0.5
    fx, fy = p[2] * sw, p[3] * sh
    k1, k2, k3, k4, k5, k6, _codx, _cody, p2, p1 = p[4:14]
    return CameraInfo(width=640, height=576, distortion_model="rational_polynomial",
                      d=[k1, k2, p1, p2, k3, k4, k5, k6],
                      k=[fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
                      r=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                      p=[fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0])


def test_real_azure_kinect_frame_comes_out_corrected(weights: dict[str, Path], tmp_path: Path,
                                                     azure_kinect_dir: Path) -> None:
    depth = np.load(azure_kinect_dir / "depth_000.npy")   # (576, 640) uint16 mm, 0 = invalid
    ir = np.load(azure_kinect_dir / "ir_000.npy")         # (576, 640) uint16, saturates at 65535
    assert depth.shape == ir.shape == (576, 640) and (ir == 65535).any() and (depth == 0).any()
    info = azure_kinect_nfov_unbinned_camera_info(azure_kinect_dir / "calibration.json")
    assert 500 < info.k[0] < 510 and 320 < info.k[2] < 345 and 330 < info.k[5] < 360
    log = tmp_path / "corrector.log"
    # A 640x576 frame is ~0.7 MB: like the Azure Kinect driver, publish it reliably (best effort
    # loses fragments of frames this large on a busy host); the outputs are reliable too.
    process = start_corrector(weights["paper"], REAL_DOMAIN, log, input_reliability="reliable",
                              output_reliability="reliable")
    got: dict[str, dict[int, object]] = {"depth": {}, "info": {}, "edges": {}, "confidence": {}}
    try:
        with listener(REAL_DOMAIN) as lis:
            node = lis.node
            base = OUTPUT.rsplit("/", 1)[0]
            for key, topic, kind in (("depth", OUTPUT, Image), ("info", f"{base}/camera_info",
                                     CameraInfo), ("edges", f"{base}/edges", Image),
                                     ("confidence", f"{base}/confidence", Image)):
                node.create_subscription(kind, topic,
                                         lambda m, k=key: got[k].__setitem__(stamp_ns(m), m),
                                         RELIABLE_DEEP)
            pubs = [node.create_publisher(kind, topic, RELIABLE_DEEP) for kind, topic in
                    ((Image, "/tof/depth/image_raw"), (Image, "/tof/amplitude/image_raw"),
                     (CameraInfo, "/tof/depth/camera_info"))]
            wait_for_corrector(lis, process, log)
            assert lis.spin_until(lambda: all(p.get_subscription_count() >= 1 for p in pubs),
                                  120.0)
            msgs = (image_message(depth, "16UC1", "depth_camera_link"),
                    image_message(ir, "mono16", "depth_camera_link"), info)
            sent = first_round_trip(lis, pubs, msgs,
                                    lambda s: all(s in v for v in got.values()), process, log)
            stamp = next(s for s in sent if all(s in v for v in got.values()))
            lis.spin_until(lambda: node_count(lis, "published") >= len(sent), 60.0)
            n_diag = len(lis.diagnostics)
            lis.spin_until(lambda: len(lis.diagnostics) >= n_diag + 2, 60.0)
            values = lis.latest_values()
    finally:
        code = stop_node(process)
    assert code == 0, log.read_text()[-3000:]
    # Every frame sent (one, or more while discovery completed) was corrected and published.
    assert values["dropped_total"] == "0", values
    assert int(values["published"]) == len(sent), values

    out, out_info = got["depth"][stamp], got["info"][stamp]
    assert (out.encoding, out.width, out.height) == ("16UC1", 180, 140)
    assert out.header.frame_id == "depth_camera_link"
    # CameraInfo of the central 180x140 crop: principal point shifted, distortion kept.
    left, top = (640 - 180) // 2, (576 - 140) // 2
    assert (out_info.width, out_info.height) == (180, 140)
    np.testing.assert_allclose([out_info.k[0], out_info.k[2], out_info.k[4], out_info.k[5]],
                               [info.k[0], info.k[2] - left, info.k[4], info.k[5] - top])
    assert out_info.distortion_model == "rational_polynomial"
    np.testing.assert_allclose(out_info.d, info.d)
    # Valid input pixels come out valid, in the same range of depths.
    raw = depth[top:top + 140, left:left + 180].astype(np.float64)
    corrected = decoded(out).astype(np.float64)
    valid_in = raw > 0
    assert valid_in.mean() > 0.5
    assert (corrected[valid_in] > 0).mean() > 0.95
    assert not (corrected[~valid_in] > 0).any()
    assert np.median(np.abs(corrected - raw)[valid_in & (corrected > 0)]) < 30.0
    edges, confidence = decoded(got["edges"][stamp]), decoded(got["confidence"][stamp])
    assert edges.shape == confidence.shape == (140, 180) and set(np.unique(edges)) <= {0, 255}
    assert np.all((confidence >= 0) & (confidence <= 1))


# -- 5. the stream corrector without ROS ------------------------------------------------------
def test_decoding_rejects_frames_with_the_reason_the_node_counts() -> None:
    ok = image_message(np.ones((4, 6), np.float32), "32FC1")
    np.testing.assert_array_equal(decode_depth(*fields(ok)), np.full((4, 6), 1000.0))
    mm = image_message(np.array([[0, 700]], np.uint16), "16UC1")
    np.testing.assert_array_equal(decode_depth(*fields(mm)), [[np.nan, 700.0]])
    with pytest.raises(FrameRejected, match="rgb8") as err:
        decode_depth("rgb8", 4, 6, 18, False, bytes(72))
    assert err.value.reason == "bad_encoding"
    with pytest.raises(FrameRejected) as err:
        decode_depth("32FC1", 4, 6, 24, False, bytes(50))
    assert err.value.reason == "bad_image"
    with pytest.raises(FrameRejected) as err:
        decode_amplitude("bgr8", 4, 6, 18, False, bytes(72))
    assert err.value.reason == "bad_encoding"


def test_stream_corrector_reasons_and_conventions(weights: dict[str, Path]) -> None:
    model = load_weights(weights["small"])
    h, w = SMALL
    k = Intrinsics.from_fov(w + 10, h + 6, 70.0)
    v, u = np.mgrid[0:k.height, 0:k.width]
    z = (300.0 + 0.5 * u + 0.3 * v).astype(np.float32)
    amp = np.full(z.shape, 800.0, np.float32)
    z_stream = DepthStreamCorrector(model, input_convention="z", threads=1)
    for depth, amplitude, intr, reason in (
            (z, amp[:-1], k, "size_mismatch"),
            (z, amp, Intrinsics.from_fov(w + 12, h + 6, 70.0), "size_mismatch"),
            (np.full_like(z, np.nan), amp, k, "no_valid_pixel")):
        with pytest.raises(FrameRejected) as err:
            z_stream.correct(depth, amplitude, intr)
        assert err.value.reason == reason
    # a frame smaller than the model's is corrected whole, as the model's central window
    small_k = Intrinsics.from_fov(w, h - 1, 70.0)
    small = z_stream.correct(z[:h - 1, :w], amp[:h - 1, :w], small_k)
    alone = correct(central_window(model, w, h - 1), small_k.z_to_radial(z[:h - 1, :w]),
                    amp[:h - 1, :w])
    assert small.depth_mm.shape == (h - 1, w)
    np.testing.assert_allclose(small.depth_mm, small_k.radial_to_z(alone.range_mm), atol=1e-3)
    # z in -> z out equals radial in -> radial out, converted per pixel of the crop.
    out_z = z_stream.correct(z, amp, k)
    crop = k.crop(w, h)
    assert out_z.intrinsics == crop and out_z.depth_mm.shape == (h, w)
    radial = DepthStreamCorrector(model, input_convention="radial", threads=1)
    rows, cols = k.crop_window(w, h)
    radial_in = np.full_like(z, np.nan)
    radial_in[rows, cols] = crop.z_to_radial(z[rows, cols])
    out_r = radial.correct(radial_in, amp, k)
    np.testing.assert_allclose(crop.radial_to_z(out_r.depth_mm), out_z.depth_mm, atol=1e-3)
    assert radial.warm_up() > 0


def test_pairer_restarts_after_a_run_of_out_of_order_stamps() -> None:
    from tof_mpd_ros.nodes.pairing import StampPairer

    pairer = StampPairer(1000, history=8, reset_after=4)
    assert pairer.add_left(10_000, "d") is None
    assert pairer.add_right(10_000, "a") == (10_000, "d", "a")
    assert pairer.add_left(20_000, "waiting") is None
    # One stray old image is dropped; an in-order one breaks the run.
    assert pairer.add_left(5_000, "old") is None and pairer.add_left(30_000, "new") is None
    assert pairer.stats.out_of_order_dropped == 1 and pairer.stats.resets == 0
    # Four in a row: the fourth restarts pairing, which discards what was waiting.
    for stamp in (1_000, 1_000, 2_000):
        pairer.add_left(stamp, "x")
    assert pairer.stats.out_of_order_dropped == 4
    assert pairer.add_right(2_000, "a2") is None
    assert pairer.stats.resets == 1 and pairer.stats.unmatched_left == 2
    assert pairer.add_left(2_000, "d2") == (2_000, "d2", "a2")
    assert StampPairer(1000).add_left(5, "x") is None  # reset_after=0: never (the default)


# -- 5. stops: a signal mid-stream ends the process cleanly ----------------------------------
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_mid_stream_stops_the_corrector_cleanly(weights: dict[str, Path],
                                                         tmp_path: Path, signum: int) -> None:
    """Frames keep coming while the node stops: its worker ends before the context goes, so
    nothing fails to publish (an internal error), no traceback, exit code 0."""
    log = tmp_path / "corrector.log"
    process = start_corrector(weights["paper"], STREAM_DOMAIN, log)
    h, w = PAPER
    v, u = np.mgrid[0:h, 0:w]
    depth = image_message((0.4 + 0.0005 * u + 0.0002 * v).astype(np.float32), "32FC1", "tof")
    amplitude = image_message((500.0 + 2.0 * u).astype(np.float32), "32FC1", "tof")
    messages = (depth, amplitude,
                camera_info_message(Intrinsics.from_fov(w, h, 60.0), "tof"))
    try:
        with listener(STREAM_DOMAIN) as lis:
            outputs: list[Image] = []
            lis.node.create_subscription(Image, OUTPUT, outputs.append, DEEP)
            qos = qos_profile_sensor_data
            publishers = [lis.node.create_publisher(Image, "/tof/depth/image_raw", qos),
                          lis.node.create_publisher(Image, "/tof/amplitude/image_raw", qos),
                          lis.node.create_publisher(CameraInfo, "/tof/depth/camera_info", qos)]
            wait_for_corrector(lis, process, log)
            deadline = time.monotonic() + 300.0
            signalled = False
            while process.poll() is None:  # ~30 Hz, until the process has ended
                assert time.monotonic() < deadline, log.read_text()[-3000:]
                send(publishers, messages, time.time_ns())
                lis.spin_until(lambda: False, 0.03)
                if not signalled and len(outputs) >= 10:  # mid-stream: the worker is busy
                    process.send_signal(signum)
                    signalled = True
            assert signalled
    finally:
        stop_node(process)
    text = log.read_text()
    assert process.returncode == 0, text[-3000:]
    assert "Traceback" not in text and "internal_error" not in text, text[-3000:]
    assert "[ERROR]" not in text, text[-3000:]
