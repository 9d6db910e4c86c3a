"""Start, spin and shut down a node with the Jazzy idiom, and stop it cleanly on a signal.

rclpy's own SIGINT/SIGTERM handlers shut the context down at once, while the nodes' worker
threads may still be publishing: they then fail ("publisher's context is invalid") and log
errors, or tracebacks, on every stop. So :func:`spin_node` installs handlers of its own that
only ask the spin loop to end; the node is then destroyed (its workers stopped and joined) while
the context is still valid, and only then is the context shut down.
"""

from __future__ import annotations

import gc
import os
import signal
import tempfile
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

# Signals that end a node cleanly: Ctrl-C, and what kill, systemd and launch send.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
# The executor waits at most this long before the spin loop looks at the stop request again: a
# Python signal handler runs only once the main thread is back from rcl_wait.
SPIN_PERIOD_S = 0.1


@contextmanager
def stop_on_signals(stop: threading.Event,
                    signals: Sequence[int] = STOP_SIGNALS) -> Iterator[threading.Event]:
    """Within the block, each of ``signals`` sets ``stop`` (instead of raising or exiting).

    The first signal also puts the previous handlers back, so a second Ctrl-C while the node
    is stopping acts as usual (forces the exit). The previous handlers are restored on leaving.
    """
    previous = {sig: signal.getsignal(sig) for sig in signals}

    def restore() -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)

    def handler(signum: int, frame: object) -> None:
        stop.set()
        restore()

    for sig in signals:
        signal.signal(sig, handler)
    try:
        yield stop
    finally:
        restore()


def spin_until_stopped(rclpy, executor, stop: threading.Event,
                       node_done: threading.Event | None = None) -> None:
    """Spin ``executor`` until ``stop`` or ``node_done`` is set or the context goes down."""
    while rclpy.ok() and not stop.is_set() and not (node_done and node_done.is_set()):
        executor.spin_once(timeout_sec=SPIN_PERIOD_S)


def spin_node(rclpy, node_factory: Callable[[], object], argv: Sequence[str]) -> int:
    """Init rclpy with ``argv``, spin the node until a stop, always clean up.

    A stop is SIGINT or SIGTERM, or the node setting its ``stop_requested`` event (a
    :class:`threading.Event`, e.g. the collector once its plan is done). The node is destroyed
    (its ``destroy_node`` stops its worker threads) before the context is shut down.

    Returns the node's ``exit_code`` attribute (0 when it has none).

    ``rclpy.init`` needs HOME or ROS_LOG_DIR for its log files; a service environment may have
    neither, so fall back to the temporary directory rather than failing.
    """
    if not os.environ.get("HOME") and not os.environ.get("ROS_LOG_DIR"):
        os.environ["ROS_LOG_DIR"] = os.path.join(tempfile.gettempdir(), "ros_log")
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    with stop_on_signals(threading.Event()) as stop:
        rclpy.init(args=["node", *argv], signal_handler_options=SignalHandlerOptions.NO)
        node = None
        exit_code = 0
        try:
            node = node_factory()
            # Everything built so far (torch, numba, the model) lives as long as the process:
            # keep it out of the cyclic GC's full collections, which otherwise stall every
            # thread for ~0.15 s now and then (frames dropped at 30 Hz).
            gc.collect()
            gc.freeze()
            # Callbacks only queue work for the nodes' own worker threads, so one executor
            # thread is enough. rclpy's MultiThreadedExecutor busy-polls its wait set while a
            # callback runs, holding the GIL: the corrector's worker then got ~1/10 of its
            # frames done.
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            spin_until_stopped(rclpy, executor, stop, getattr(node, "stop_requested", None))
        except ExternalShutdownException:
            pass
        except RuntimeError:
            # Something shut the context down while the executor built its wait set; rclpy then
            # raises RCLError ("context is not valid"). Anything raised while it is still valid
            # is a real error.
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
    quickly, and after the OpenMP wait policy is chosen. A
    :class:`~tof_mpd_ros.errors.TofMpdError` at start-up (e.g. corrupt weights) is one clear line
    and exit code 2.
    """
    import importlib
    import sys

    from ..errors import TofMpdError
    from ..machine import set_openmp_wait_policy
    from .launch_args import node_parser, strip_ros_args

    set_openmp_wait_policy()  # before the node module loads numba and torch
    argv = list(sys.argv[1:] if args is None else args)
    node_parser(prog, description).parse_args(strip_ros_args(argv))
    import rclpy

    factory = getattr(importlib.import_module(f"{__package__}.{node_module}"), node_class)
    try:
        return spin_node(rclpy, factory, argv)
    except TofMpdError as err:
        print(f"{prog}: cannot start: {err}", file=sys.stderr)
        return 2
