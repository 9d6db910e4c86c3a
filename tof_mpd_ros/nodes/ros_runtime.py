"""Start, spin and shut down a node with the Jazzy idiom."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Sequence


def spin_node(rclpy, node_factory: Callable[[], object], argv: Sequence[str]) -> int:
    """Init rclpy with ``argv``, spin the node until shutdown, always clean up.

    ``rclpy.init`` needs HOME or ROS_LOG_DIR for its log files; a service environment may have
    neither, so fall back to the temporary directory rather than failing.
    """
    if not os.environ.get("HOME") and not os.environ.get("ROS_LOG_DIR"):
        os.environ["ROS_LOG_DIR"] = os.path.join(tempfile.gettempdir(), "ros_log")
    from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor

    rclpy.init(args=["node", *argv])
    node = None
    try:
        node = node_factory()
        executor = MultiThreadedExecutor(num_threads=2)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
