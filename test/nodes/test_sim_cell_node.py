"""The sim_cell node in its own process (loopback only): unusable arm poses, clean stops."""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from ros_harness import domain_id, spin_until, start_node, stop_node  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402

from tof_mpd_ros.arm.tool import DEFAULT_T_FLANGE_CAMERA_M  # noqa: E402
from tof_mpd_ros.nodes.ros_messages import pose_message, stamp_ns  # noqa: E402
from tof_mpd_ros.sim.viewpoints import sim_plan  # noqa: E402

DOMAIN = domain_id(9)
DEPTH = "/tof/depth/image_raw"
# what the collector publishes its TCP pose with
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
BEST_EFFORT = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)


@contextlib.contextmanager
def client(domain: int) -> Iterator[tuple[object, SingleThreadedExecutor, list[Image]]]:
    """A node in the test process on ``domain`` that collects the depth images it receives."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    node = rclpy.create_node(f"sim_cell_test_{domain}", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    images: list[Image] = []
    node.create_subscription(Image, DEPTH, images.append, BEST_EFFORT)
    try:
        yield node, executor, images
    finally:
        executor.shutdown()
        node.destroy_node()
        context.try_shutdown()


def tcp_pose(x: float = 0.0, y: float = 0.0, z: float = 0.0, w: float = 1.0,
             position: tuple[float, float, float] | None = None) -> PoseStamped:
    """The first planned view's TCP pose, or one with the given quaternion / position."""
    tcp = sim_plan(0, "test", 0, 1, DEFAULT_T_FLANGE_CAMERA_M)[0].tcp_to_base_m
    msg = PoseStamped(pose=pose_message(tcp))
    msg.header.frame_id = "base"
    if (x, y, z, w) != (0.0, 0.0, 0.0, 1.0):
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = x, y, z, w
    if position is not None:
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = position
    return msg


def test_unusable_arm_poses_are_ignored_and_rendering_goes_on(tmp_path: Path) -> None:
    """A zero quaternion and a NaN position on the TCP pose topic: each is a warning; the next
    valid pose is rendered and published."""
    log = tmp_path / "sim_cell.log"
    process = start_node("sim_cell", {"views": 1, "rate_hz": 10.0}, DOMAIN, log)
    try:
        with client(DOMAIN) as (node, executor, images):
            def until(condition, timeout: float) -> bool:
                return spin_until(node, executor, lambda: condition() or
                                  process.poll() is not None, timeout)

            pub = node.create_publisher(PoseStamped, "/arm/tcp_pose", LATCHED)
            assert until(lambda: pub.get_subscription_count() >= 1, 120), log.read_text()
            for bad in (tcp_pose(0.0, 0.0, 0.0, 0.0), tcp_pose(position=(np.nan, 0.0, 0.5))):
                pub.publish(bad)
                assert until(lambda: "ignored a TCP pose" in log.read_text(), 60), \
                    log.read_text()[-3000:]
                assert process.poll() is None, log.read_text()[-3000:]
            n_warnings = log.read_text().count("ignored a TCP pose")
            good = tcp_pose()
            good.header.stamp = node.get_clock().now().to_msg()
            pub.publish(good)
            sent_ns = stamp_ns(good)
            assert until(lambda: any(stamp_ns(m) > sent_ns for m in images), 300), \
                log.read_text()[-3000:]
            assert process.poll() is None
    finally:
        code = stop_node(process)
    text = log.read_text()
    assert code == 0 and "Traceback" not in text, text[-3000:]
    assert n_warnings == 2, text[-3000:]


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_mid_stream_stops_sim_cell_cleanly(tmp_path: Path, signum: int) -> None:
    log = tmp_path / "sim_cell.log"
    process = start_node("sim_cell", {"views": 1, "rate_hz": 30.0}, DOMAIN, log)
    try:
        with client(DOMAIN) as (node, executor, images):
            assert spin_until(node, executor, lambda: len(images) >= 10 or
                              process.poll() is not None, 300), log.read_text()[-3000:]
            process.send_signal(signum)
            code = process.wait(60)
    finally:
        stop_node(process)
    text = log.read_text()
    assert code == 0, text[-3000:]
    assert "Traceback" not in text, text[-3000:]
