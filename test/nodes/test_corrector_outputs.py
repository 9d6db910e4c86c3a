"""The corrector's outputs beyond the corrected image, and its parameters changed at run time.

* ``depth_corrected/points`` and ``depth_corrected/input_points`` (organized clouds of the crop)
  and ``depth_corrected/correction`` (corrected - input) agree number for number with the
  corrected image, the input and the published CameraInfo, keep the input's header, and are
  computed only while something subscribes to them;
* every parameter but the QoS ones changes while the node runs, through the node's
  ``set_parameters`` service, and the next outputs follow: a bad value (a corrupt weights file,
  crossed edge thresholds, a device the model cannot use) is refused with its reason and the
  outputs go on unchanged;
* weights of the fcn kind load at run time: the confidence image is then the predicted σ in
  metres (``sigma_mm / 1000`` of ``correct`` itself), the edge map empty, and a patch-only
  parameter is accepted and ignored with one warning.

The corrector runs in its own process (loopback, this file's ROS domain) with untrained weights
and hand-made frames; the expected outputs are ``DepthStreamCorrector`` run in this process on
the same input. The on-demand test runs the node inside this process instead, so that it can
watch which outputs the node builds. Every wait is for a condition with a generous timeout; no
test depends on speed.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from builtin_interfaces.msg import Time  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rcl_interfaces.msg import SetParametersResult  # noqa: E402
from rcl_interfaces.srv import SetParameters  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import (  # noqa: E402
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from ros_harness import domain_id, spin_until, start_node, stop_node  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image, PointCloud2, PointField  # noqa: E402

from tof_mpd_ros.calibration import IntrinsicCalibration  # noqa: E402
from tof_mpd_ros.camera import Intrinsics  # noqa: E402
from tof_mpd_ros.correction.depth_stream import (  # noqa: E402
    DepthStreamCorrector,
    StreamResult,
    decode_amplitude,
    decode_depth,
)
from tof_mpd_ros.correction.fcn import FCNCorrectionModel  # noqa: E402
from tof_mpd_ros.correction.pipeline import CorrectionModel, GeodesicParams, correct  # noqa: E402
from tof_mpd_ros.correction.weights import load_weights, save_weights  # noqa: E402
from tof_mpd_ros.image_encoding import image_to_array  # noqa: E402
from tof_mpd_ros.machine import slow_precision  # noqa: E402
from tof_mpd_ros.nodes import corrector_node  # noqa: E402
from tof_mpd_ros.nodes.corrector_node import PUBLISHED, TOPICS, CorrectorNode  # noqa: E402
from tof_mpd_ros.nodes.ros_messages import (  # noqa: E402
    camera_info_message,
    image_message,
    point_cloud_message,
    stamp_ns,
)

DOMAIN = domain_id(12)
NAMESPACE = "/tof"
MODEL_HW = (24, 32)  # (H, W): the weights' processed window
FRAME_HW = (30, 42)  # (H, W) of the frames sent: the window is their centre, 3 rows, 5 columns in
FRAME_ID = "tof_optical_frame"
# Non-square pixels and an off-centre principal point: a swapped fx/fy or cx/cy, or the full
# frame's principal point used for the crop, shows in the numbers.
INTRINSICS = Intrinsics(fx=38.0, fy=45.0, cx=19.25, cy=13.75, width=FRAME_HW[1],
                        height=FRAME_HW[0])
TOP, LEFT = 3, 5
# In the crop: an invalid depth (NaN), a zero depth, and a valid depth whose amplitude is 0
# (the pipeline leaves that pixel invalid: corrected NaN, input valid).
NAN_PIXEL, ZERO_PIXEL, DARK_PIXEL = (5, 9), (8, 12), (12, 20)
DEEP = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                  depth=100)
TIMEOUT_S = 300.0


def resolved(key: str, namespace: str = NAMESPACE) -> str:
    """The topic the node publishes output ``key`` on (its table, resolved in ``namespace``)."""
    return f"{namespace}/{TOPICS[key]}"


def frame() -> tuple[np.ndarray, np.ndarray]:
    """(FRAME_HW) float32 z-depth in metres (a tilted plane with a 5 cm step, for G) and
    amplitude, with the invalid pixels above (crop coordinates + the window's offset)."""
    v, u = np.mgrid[0:FRAME_HW[0], 0:FRAME_HW[1]]
    depth = (0.45 + 0.002 * u + 0.001 * v + 0.05 * (u >= 21)).astype(np.float32)
    amplitude = (400.0 + 3.0 * v + 0.5 * u).astype(np.float32)
    depth[NAN_PIXEL[0] + TOP, NAN_PIXEL[1] + LEFT] = np.nan
    depth[ZERO_PIXEL[0] + TOP, ZERO_PIXEL[1] + LEFT] = 0.0
    amplitude[DARK_PIXEL[0] + TOP, DARK_PIXEL[1] + LEFT] = 0.0
    return depth, amplitude


def decoded(msg: Image) -> np.ndarray:
    return image_to_array(msg.encoding, msg.height, msg.width, msg.step,
                          bool(msg.is_bigendian), msg.data)


def cloud_array(msg: PointCloud2) -> np.ndarray:
    """(height, width) structured array read through the message's own field table."""
    types = {PointField.FLOAT32: "<f4", PointField.FLOAT64: "<f8"}
    dtype = np.dtype({"names": [f.name for f in msg.fields],
                      "formats": [types[f.datatype] for f in msg.fields],
                      "offsets": [f.offset for f in msg.fields], "itemsize": msg.point_step})
    assert msg.row_step == msg.point_step * msg.width and not msg.is_bigendian
    return np.frombuffer(bytes(msg.data), dtype).reshape(msg.height, msg.width)


def received_frame() -> tuple[np.ndarray, np.ndarray]:
    """:func:`frame` as the node decodes it from its messages: depth in mm, amplitude."""
    depth, amplitude = frame()
    depth_msg, amp_msg = image_message(depth, "32FC1"), image_message(amplitude, "32FC1")
    fields = [(m.encoding, m.height, m.width, m.step, False, m.data)
              for m in (depth_msg, amp_msg)]
    return decode_depth(*fields[0]), decode_amplitude(*fields[1])


def offline(weights_path: Path, *, convention: str = "z",
            geodesic: GeodesicParams | None = None) -> StreamResult:
    """What the node should publish for :func:`frame`: the stream corrector run here, on the
    frame decoded from the messages the node receives."""
    model = load_weights(weights_path)
    stream = DepthStreamCorrector(model, input_convention=convention, threads=1,
                                  geodesic=geodesic)
    return stream.correct(*received_frame(), INTRINSICS)


def assert_depth_equals(msg: Image, depth_mm: np.ndarray) -> None:
    """A 32FC1 output equals ``depth_mm`` within float32 metres (1e-3 mm), NaN alike."""
    assert msg.encoding == "32FC1" and (msg.height, msg.width) == MODEL_HW
    got_mm = decoded(msg).astype(np.float64) * 1000.0
    np.testing.assert_array_equal(np.isnan(got_mm), np.isnan(depth_mm))
    np.testing.assert_allclose(got_mm, depth_mm, rtol=0, atol=1e-3, equal_nan=True)


@pytest.fixture(scope="module")
def weights(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Two untrained models of the window (different seeds), one of the fcn kind and a
    corrupt weights file."""
    out = tmp_path_factory.mktemp("weights")
    paths = {name: save_weights(out / f"{name}.npz", CorrectionModel.untrained(
        IntrinsicCalibration.identity(*MODEL_HW), seed=seed))
        for name, seed in (("a", 3), ("b", 11))}
    paths["fcn"] = save_weights(out / "fcn.npz", FCNCorrectionModel.untrained(
        IntrinsicCalibration.identity(*MODEL_HW), seed=4))
    data = paths["a"].read_bytes()
    paths["corrupt"] = out / "corrupt.npz"
    paths["corrupt"].write_bytes(data[: len(data) // 2])
    return paths


# -- the message itself, no node -------------------------------------------------------------
def test_point_cloud_message_is_organized_float32_with_nan_points() -> None:
    from std_msgs.msg import Header

    points = np.arange(2 * 3 * 3, dtype=np.float32).reshape(2, 3, 3) / 10.0
    points[1, 2] = np.nan
    intensity = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], np.float32)
    header = Header(frame_id="cam")
    header.stamp.sec, header.stamp.nanosec = 12, 345
    msg = point_cloud_message(points, intensity, header)
    assert (msg.height, msg.width, msg.point_step, msg.row_step) == (2, 3, 16, 48)
    assert not msg.is_dense and not msg.is_bigendian
    assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [
        ("x", 0, PointField.FLOAT32, 1), ("y", 4, PointField.FLOAT32, 1),
        ("z", 8, PointField.FLOAT32, 1), ("intensity", 12, PointField.FLOAT32, 1)]
    assert msg.header.frame_id == "cam" and stamp_ns(msg) == 12_000_000_345
    cloud = cloud_array(msg)
    np.testing.assert_array_equal(np.stack([cloud["x"], cloud["y"], cloud["z"]], axis=-1),
                                  points)
    np.testing.assert_array_equal(cloud["intensity"], intensity)
    assert cloud["y"][0, 1] == np.float32(0.4)  # row-major: point (v=0, u=1) is the second


# -- 1. computed only while subscribed (the node inside this process) -------------------------
def test_on_demand_outputs_are_built_only_while_someone_subscribes(
        weights: dict[str, Path], monkeypatch: pytest.MonkeyPatch) -> None:
    """No subscriber: the node never builds a cloud or a correction image while the corrected
    image flows. A subscriber to ``points`` only: clouds of the corrected depth are built and
    arrive, still no input cloud or correction. It leaves: no more clouds are built."""
    built: collections.Counter[str] = collections.Counter()
    real = corrector_node.on_demand_message

    def spy(key, *args):
        built[key] += 1
        return real(key, *args)

    monkeypatch.setattr(corrector_node, "on_demand_message", spy)
    namespace = "/in_process"  # apart from the other tests' /tof, should they overlap
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN)
    node = CorrectorNode(context=context, namespace=namespace, parameter_overrides=[
        Parameter("weights_path", value=str(weights["a"]))])
    test = rclpy.create_node("on_demand_test", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(test)
    images: list[int] = []
    clouds: list[int] = []
    test.create_subscription(Image, resolved("output", namespace),
                             lambda m: images.append(stamp_ns(m)), DEEP)
    qos = qos_profile_sensor_data
    pubs = [test.create_publisher(Image, f"{namespace}/{TOPICS['depth']}", qos),
            test.create_publisher(Image, f"{namespace}/{TOPICS['amplitude']}", qos),
            test.create_publisher(CameraInfo, f"{namespace}/{TOPICS['camera_info']}", qos)]
    depth, amplitude = frame()
    messages = (image_message(depth, "32FC1", FRAME_ID), image_message(amplitude, "32FC1",
                FRAME_ID), camera_info_message(INTRINSICS, FRAME_ID))

    def corrected(n: int) -> None:
        """Send frames until ``n`` more corrected images came back."""
        goal = len(images) + n
        deadline = time.monotonic() + TIMEOUT_S
        while len(images) < goal:
            assert time.monotonic() < deadline, "no corrected image came back"
            send(pubs, messages, time.time_ns())
            spin_until(test, executor, lambda: len(images) >= goal, 2.0)

    try:
        corrected(3)
        assert not built, built
        sub = test.create_subscription(PointCloud2, resolved("points", namespace),
                                       lambda m: clouds.append(stamp_ns(m)), DEEP)
        assert spin_until(test, executor,
                          lambda: node.pubs["points"].get_subscription_count() == 1, 60.0)
        corrected(3)
        assert spin_until(test, executor, lambda: len(clouds) >= 1, 60.0)
        assert built["points"] >= 1 and set(built) == {"points"}, built
        assert set(clouds) <= set(images)
        test.destroy_subscription(sub)
        assert spin_until(test, executor,
                          lambda: node.pubs["points"].get_subscription_count() == 0, 60.0)
        before = dict(built)
        corrected(3)
        assert dict(built) == before
    finally:
        executor.shutdown()
        node.destroy_node()
        test.destroy_node()
        context.try_shutdown()


def send(publishers: list, messages: tuple, stamp: int) -> None:
    """Publish (depth, amplitude, CameraInfo), CameraInfo first, all stamped ``stamp`` (ns)."""
    t = Time(sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000)
    for i in (2, 0, 1):
        messages[i].header.stamp = t
        publishers[i].publish(messages[i])


# -- 2. a corrector process, its outputs and its parameters ----------------------------------
@dataclass
class Rig:
    """The corrector in namespace /tof and a node of this process that feeds and watches it."""

    node: object
    executor: SingleThreadedExecutor
    process: object
    log: Path
    publishers: list
    client: object
    received: dict[str, dict[int, object]] = field(default_factory=dict)
    diagnostics: list[float] = field(default_factory=list)  # monotonic arrival times

    def spin_until(self, condition, timeout: float = TIMEOUT_S) -> bool:
        return spin_until(self.node, self.executor, condition, timeout)

    def round_trip(self, keys: tuple[str, ...] = tuple(PUBLISHED)) -> dict[str, object]:
        """Send :func:`frame` with fresh stamps until one comes back on every output of
        ``keys``; returns that stamp's output messages. Sent after a parameter change was
        accepted, it shows the change (the node swaps before it answers)."""
        depth, amplitude = frame()
        messages = (image_message(depth, "32FC1", FRAME_ID),
                    image_message(amplitude, "32FC1", FRAME_ID),
                    camera_info_message(INTRINSICS, FRAME_ID))
        sent: list[int] = []

        def complete() -> int | None:
            return next((s for s in sent if all(s in self.received[k] for k in keys)), None)

        deadline = time.monotonic() + TIMEOUT_S
        while complete() is None:
            assert time.monotonic() < deadline and self.process.poll() is None, \
                self.log.read_text()[-3000:]
            sent.append(time.time_ns())
            send(self.publishers, messages, sent[-1])
            self.spin_until(lambda: complete() is not None, 3.0)
        stamp = complete()
        return {k: self.received[k][stamp] for k in keys}

    def set(self, **values: object) -> list[SetParametersResult]:
        """``/tof/corrector/set_parameters`` with ``values``; one result per parameter."""
        request = SetParameters.Request(parameters=[
            Parameter(name, value=value).to_parameter_msg() for name, value in values.items()])
        future = self.client.call_async(request)
        assert self.spin_until(future.done, 120.0), "no answer from set_parameters"
        return list(future.result().results)

    def accept(self, **values: object) -> None:
        results = self.set(**values)
        assert all(r.successful for r in results), [r.reason for r in results]


@pytest.fixture(scope="module")
def rig(weights: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    log = tmp_path_factory.mktemp("corrector_outputs") / "corrector.log"
    process = start_node("corrector", {"weights_path": str(weights["a"]),
                                       "diagnostics_period_s": 0.25}, DOMAIN, log,
                         remap=[f"__ns:={NAMESPACE}"])
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN)
    node = rclpy.create_node("corrector_outputs_test", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    qos = qos_profile_sensor_data
    publishers = [node.create_publisher(Image, f"{NAMESPACE}/{TOPICS['depth']}", qos),
                  node.create_publisher(Image, f"{NAMESPACE}/{TOPICS['amplitude']}", qos),
                  node.create_publisher(CameraInfo, f"{NAMESPACE}/{TOPICS['camera_info']}",
                                        qos)]
    client = node.create_client(SetParameters, f"{NAMESPACE}/corrector/set_parameters")
    r = Rig(node, executor, process, log, publishers, client)
    for key, kind in PUBLISHED.items():
        r.received[key] = {}
        node.create_subscription(kind, resolved(key),
                                 lambda m, k=key: r.received[k].__setitem__(stamp_ns(m), m),
                                 DEEP)

    def on_diagnostics(msg: DiagnosticArray) -> None:
        if any(s.name == "tof_mpd_ros: corrector" and s.hardware_id.startswith(NAMESPACE)
               for s in msg.status):
            r.diagnostics.append(time.monotonic())

    node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 100)
    try:
        assert r.spin_until(lambda: bool(r.diagnostics) or process.poll() is not None), \
            log.read_text()[-3000:]
        assert client.wait_for_service(timeout_sec=120.0)
        r.round_trip()
        yield r
        assert process.poll() is None, "the corrector exited"
    finally:
        executor.shutdown()
        node.destroy_node()
        context.try_shutdown()
        code = stop_node(process)
    text = log.read_text()
    assert code == 0, text[-3000:]
    assert "Traceback" not in text


def test_clouds_and_correction_agree_with_the_image_the_input_and_the_camera_info(
        rig: Rig, weights: dict[str, Path]) -> None:
    out = rig.round_trip()
    stamp = stamp_ns(out["output"])
    for key, msg in out.items():  # every output keeps the input's header
        assert stamp_ns(msg) == stamp and msg.header.frame_id == FRAME_ID, key
    depth, amplitude = frame()
    crop = (slice(TOP, TOP + MODEL_HW[0]), slice(LEFT, LEFT + MODEL_HW[1]))
    input_m = np.where(depth[crop] > 0, depth[crop], np.nan)
    image = decoded(out["output"])  # corrected z-depth, metres
    assert_depth_equals(out["output"], offline(weights["a"]).depth_mm)
    # The frame exercises each case: the dark pixel is input-valid but corrected-invalid.
    assert np.isnan(input_m[NAN_PIXEL]) and np.isnan(input_m[ZERO_PIXEL])
    assert np.isfinite(input_m[DARK_PIXEL]) and np.isnan(image[DARK_PIXEL])

    # The crop's intrinsics: the principal point moves by the window's offset.
    info = out["output_camera_info"]
    fx, cx, fy, cy = info.k[0], info.k[2], info.k[4], info.k[5]
    assert (fx, fy, cx, cy) == (38.0, 45.0, 19.25 - LEFT, 13.75 - TOP)
    assert (info.width, info.height) == (MODEL_HW[1], MODEL_HW[0])

    v, u = np.mgrid[0:MODEL_HW[0], 0:MODEL_HW[1]]
    for key, z_ref in (("points", image), ("input_points", input_m)):
        msg = out[key]
        assert (msg.height, msg.width) == MODEL_HW and not msg.is_dense
        assert [f.name for f in msg.fields] == ["x", "y", "z", "intensity"]
        assert all(f.datatype == PointField.FLOAT32 for f in msg.fields)
        cloud = cloud_array(msg)
        invalid = np.isnan(z_ref)
        for axis in "xyz":  # NaN exactly at the invalid pixels
            np.testing.assert_array_equal(np.isnan(cloud[axis]), invalid, f"{key}.{axis}")
        z = cloud["z"]
        np.testing.assert_allclose(z[~invalid], z_ref[~invalid], rtol=1e-6)
        # The pinhole model of the published CameraInfo, everywhere and at one pixel by hand.
        np.testing.assert_allclose(cloud["x"][~invalid], ((u - cx) * z / fx)[~invalid],
                                   rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(cloud["y"][~invalid], ((v - cy) * z / fy)[~invalid],
                                   rtol=1e-5, atol=1e-7)
        pu, pv = 25, 17
        assert cloud["x"][pv, pu] == pytest.approx((25 - 14.25) * z[pv, pu] / 38.0, rel=1e-5)
        assert cloud["y"][pv, pu] == pytest.approx((17 - 10.75) * z[pv, pu] / 45.0, rel=1e-5)
        np.testing.assert_array_equal(cloud["intensity"], amplitude[crop])  # the amplitude

    correction = decoded(out["correction"])
    assert out["correction"].encoding == "32FC1" and correction.shape == MODEL_HW
    either = np.isnan(image) | np.isnan(input_m)
    np.testing.assert_array_equal(np.isnan(correction), either)
    np.testing.assert_allclose(correction[~either], (image - input_m)[~either], rtol=0,
                               atol=1e-6)
    assert np.nanmax(np.abs(correction)) > 1e-4  # the (untrained) correction did something


def test_input_convention_changes_at_run_time(rig: Rig, weights: dict[str, Path]) -> None:
    """radial: the same numbers are taken as radial range, the output is radial and the cloud
    puts each point at that distance along its ray; back to z afterwards."""
    rig.accept(input_convention="radial")
    try:
        out = rig.round_trip(("output", "points"))
        expected = offline(weights["a"], convention="radial").depth_mm
        assert_depth_equals(out["output"], expected)
        assert not np.allclose(expected, offline(weights["a"]).depth_mm, equal_nan=True)
        cloud = cloud_array(out["points"])
        norm = np.sqrt(cloud["x"].astype(np.float64) ** 2 + cloud["y"] ** 2 + cloud["z"] ** 2)
        valid = np.isfinite(expected)
        np.testing.assert_allclose(norm[valid], expected[valid] / 1000.0, rtol=1e-6)
    finally:
        rig.accept(input_convention="z")
    assert_depth_equals(rig.round_trip(("output",))["output"], offline(weights["a"]).depth_mm)


def test_weights_path_changes_at_run_time_and_a_corrupt_file_is_refused(
        rig: Rig, weights: dict[str, Path]) -> None:
    a, b = offline(weights["a"]).depth_mm, offline(weights["b"]).depth_mm
    assert not np.allclose(a, b, equal_nan=True)  # the two weights give different outputs
    rig.accept(weights_path=str(weights["b"]))
    try:
        assert_depth_equals(rig.round_trip(("output",))["output"], b)
        for bad in (weights["corrupt"], weights["corrupt"].with_name("missing.npz")):
            [result] = rig.set(weights_path=str(bad))
            assert not result.successful
            assert str(bad) in result.reason and str(weights["b"]) in result.reason, \
                result.reason
            assert_depth_equals(rig.round_trip(("output",))["output"], b)  # unchanged
    finally:
        rig.accept(weights_path=str(weights["a"]))
    assert_depth_equals(rig.round_trip(("output",))["output"], a)


def test_edge_thresholds_and_geodesic_constants_change_at_run_time(
        rig: Rig, weights: dict[str, Path]) -> None:
    """Defaults stand for the weights file's values; set, they reach the edge map and the
    filter (the outputs equal the offline correction with those constants); crossed
    thresholds are refused."""
    default = offline(weights["a"])
    every_maximum = GeodesicParams(edge_low=0.0, edge_high=0.0, k=9, sigma=1.0)
    knobs = offline(weights["a"], geodesic=every_maximum)
    assert knobs.edges.sum() > default.edges.sum()
    try:
        rig.accept(edge_low=0.0)
        rig.accept(edge_high=0.0, geodesic_k=9, geodesic_sigma=1.0)
        out = rig.round_trip(("output", "edges"))
        np.testing.assert_array_equal(decoded(out["edges"]) == 255, knobs.edges)
        assert_depth_equals(out["output"], knobs.depth_mm)
        [result] = rig.set(edge_low=0.5)  # above edge_high 0.0
        assert not result.successful and "edge_low" in result.reason, result.reason
        [result] = rig.set(geodesic_k=-1)  # out of its range
        assert not result.successful
    finally:
        rig.accept(edge_high=-1.0, edge_low=-1.0, geodesic_k=0, geodesic_sigma=0.0)
    out = rig.round_trip(("output", "edges"))
    np.testing.assert_array_equal(decoded(out["edges"]) == 255, default.edges)
    assert_depth_equals(out["output"], default.depth_mm)


def test_encoding_queue_threads_and_diagnostics_period_change_at_run_time(
        rig: Rig, weights: dict[str, Path]) -> None:
    expected = offline(weights["a"]).depth_mm
    rig.accept(output_encoding="16UC1")
    try:
        out = rig.round_trip(("output",))["output"]
        assert out.encoding == "16UC1"
        np.testing.assert_array_equal(decoded(out),
                                      np.where(np.isnan(expected), 0, np.rint(expected)))
    finally:
        rig.accept(output_encoding="input")
    rig.accept(queue_size=5, threads=2)
    try:
        assert not rig.set(queue_size=0)[0].successful
        assert_depth_equals(rig.round_trip(("output",))["output"], expected)
    finally:
        rig.accept(queue_size=2, threads=1)
    # A long period: at most the message already on its way arrives in the next seconds...
    rig.accept(diagnostics_period_s=60.0)
    try:
        rig.spin_until(lambda: False, 3.0)
        seen = len(rig.diagnostics)
        rig.spin_until(lambda: False, 8.0)
        assert len(rig.diagnostics) <= seen + 1
    finally:
        rig.accept(diagnostics_period_s=0.25)
    # ...and a short one brings them back at once (three within 30 s, however busy the
    # machine), not when the 60 s period that started 11 s ago ends.
    seen = len(rig.diagnostics)
    assert rig.spin_until(lambda: len(rig.diagnostics) >= seen + 3, 30.0)


def test_a_device_the_model_cannot_use_and_qos_parameters_are_refused(
        rig: Rig, weights: dict[str, Path]) -> None:
    [result] = rig.set(device="cuda:7")
    assert not result.successful and "cuda:7" in result.reason, result.reason
    for name, value in (("input_reliability", "reliable"), ("output_reliability",
                                                            "best_effort"),
                        ("input_depth", 20)):
        [result] = rig.set(**{name: value})
        assert not result.successful and "read-only" in result.reason, (name, result.reason)
    assert_depth_equals(rig.round_trip(("output",))["output"], offline(weights["a"]).depth_mm)


def test_weights_of_the_fcn_kind_load_at_run_time_and_publish_sigma_in_metres(
        rig: Rig, weights: dict[str, Path]) -> None:
    """Switched to fcn weights, the node publishes that model's depth, an empty edge map and,
    as confidence, the predicted σ in metres: in the radial convention exactly ``sigma_mm /
    1000`` of ``correct`` on the decoded window (z: the σ of the z-depth, as the stream
    corrector computes it). A patch-only parameter set meanwhile is accepted, ignored and
    logged once. Back to the patch weights, the outputs are theirs again."""
    rig.accept(weights_path=str(weights["fcn"]))
    try:
        out = rig.round_trip(("output", "confidence", "edges"))
        expected = offline(weights["fcn"])
        assert_depth_equals(out["output"], expected.depth_mm)
        assert out["confidence"].encoding == "32FC1"
        np.testing.assert_allclose(decoded(out["confidence"]), expected.sigma_mm / 1000.0,
                                   rtol=1e-6, equal_nan=True)
        assert not decoded(out["edges"]).any()

        rig.accept(input_convention="radial", edge_low=0.2)
        out = rig.round_trip(("output", "confidence"))
        depth_mm, amplitude = received_frame()
        crop = (slice(TOP, TOP + MODEL_HW[0]), slice(LEFT, LEFT + MODEL_HW[1]))
        direct = correct(load_weights(weights["fcn"]), depth_mm[crop], amplitude[crop])
        confidence = decoded(out["confidence"])
        np.testing.assert_allclose(confidence, direct.sigma_mm / 1000.0, rtol=1e-6,
                                   equal_nan=True)
        np.testing.assert_array_equal(np.isnan(confidence), ~direct.valid)
        assert 1e-4 < np.nanmin(confidence) and np.nanmax(confidence) < 0.05  # mm of σ, in m
        assert_depth_equals(out["output"], direct.range_mm)
        warned = "ignoring edge_low=0.2: weights of the fcn kind have no G"
        assert rig.spin_until(lambda: warned in rig.log.read_text(), 30.0)
    finally:
        rig.accept(weights_path=str(weights["a"]), input_convention="z", edge_low=-1.0)
    assert_depth_equals(rig.round_trip(("output",))["output"], offline(weights["a"]).depth_mm)
    assert rig.log.read_text().count("ignoring edge_low") == 1


def test_a_reduced_precision_this_cpu_has_no_instructions_for_is_logged_once(
        rig: Rig, weights: dict[str, Path]) -> None:
    """Switched to bfloat16, the node corrects in it and, where this machine's CPU lacks the
    bfloat16 instructions (a reference kernel, many times slower), says so in its log, once;
    where it has them, says nothing. Back to float32, the outputs are float32's again."""
    said = "precision 'bfloat16' without its instructions"
    rig.accept(precision="bfloat16")
    try:
        out = rig.round_trip(("output",))         # answered: the swap and its warnings are done
        expected = offline(weights["a"])
        got_mm = decoded(out["output"]).astype(np.float64) * 1e3
        np.testing.assert_array_equal(np.isnan(got_mm), np.isnan(expected.depth_mm))
        assert np.nanmax(np.abs(got_mm - expected.depth_mm)) < 0.5     # mm: F in bfloat16
        if slow_precision("bfloat16") is None:
            assert said not in rig.log.read_text()
        else:
            assert rig.spin_until(lambda: said in rig.log.read_text(), 30.0)
    finally:
        rig.accept(precision="float32")
    assert_depth_equals(rig.round_trip(("output",))["output"], expected.depth_mm)
    assert rig.log.read_text().count(said) == (slow_precision("bfloat16") is not None)
