"""Start, spin and shut down a node with the Jazzy idiom."""

from __future__ import annotations

import gc
import os
import tempfile
from collections.abc import Callable, Sequence


def spin_node(rclpy, node_factory: Callable[[], object], argv: Sequence[str]) -> int:
    """Init rclpy with ``argv``, spin the node until shutdown, always clean up.

    Returns the node's ``exit_code`` attribute (0 when it has none).

    ``rclpy.init`` needs HOME or ROS_LOG_DIR for its log files; a service environment may have
    neither, so fall back to the temporary directory rather than failing.
    """
    if not os.environ.get("HOME") and not os.environ.get("ROS_LOG_DIR"):
        os.environ["ROS_LOG_DIR"] = os.path.join(tempfile.gettempdir(), "ros_log")
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    rclpy.init(args=["node", *argv])
    node = None
    exit_code = 0
    try:
        node = node_factory()
        # Everything built so far (torch, numba, the model) lives as long as the process: keep
        # it out of the cyclic GC's full collections, which otherwise stall every thread for
        # ~0.15 s now and then (frames dropped at 30 Hz).
        gc.collect()
        gc.freeze()
        # Callbacks only queue work for the nodes' own worker threads, so one executor thread is
        # enough. rclpy's MultiThreadedExecutor busy-polls its wait set while a callback runs,
        # holding the GIL: the corrector's worker then got ~1/10 of its frames done.
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        # A SIGINT can shut the context down while the executor is building its wait set; rclpy
        # then raises RCLError ("context is not valid") instead of ExternalShutdownException.
        # That is a normal stop; anything raised while the context is still valid is not.
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            exit_code = int(getattr(node, "exit_code", 0))
            node.destroy_node()
        rclpy.try_shutdown()
    return exit_code


def node_main(prog: str, description: str, node_module: str, node_class: str,
              args: Sequence[str] | None) -> int:
    """Body of a node executable's ``main``: parse ``--help``, then start and spin the node.

    The node module (and rclpy) is imported only after argument parsing, so ``--help`` works
    quickly. A :class:`~tof_mpd_ros.errors.TofMpdError` at start-up (e.g. corrupt weights) is
    one clear line and exit code 2.
    """
    import importlib
    import sys

    from ..errors import TofMpdError
    from .launch_args import node_parser, strip_ros_args

    argv = list(sys.argv[1:] if args is None else args)
    node_parser(prog, description).parse_args(strip_ros_args(argv))
    import rclpy

    factory = getattr(importlib.import_module(f"{__package__}.{node_module}"), node_class)
    try:
        return spin_node(rclpy, factory, argv)
    except TofMpdError as err:
        print(f"{prog}: cannot start: {err}", file=sys.stderr)
        return 2
