"""The corrector node with faults injected on request, for the fault tests (run as a script).

A pair whose depth image's ``frame_id`` names a fault meets it in the worker:

* ``fault/pipeline``: the correction raises (a bug deep in the pipeline);
* ``fault/publish``: publishing the corrected depth raises rclpy's ``RCLError``;
* ``fault/slow``: the correction first sleeps :data:`SLOW_S` (the queue fills behind it).

Every other pair goes through the real node unchanged.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import Any

import rclpy
from rclpy._rclpy_pybind11 import RCLError

from tof_mpd_ros.nodes.corrector_node import CorrectorNode, _Pair
from tof_mpd_ros.nodes.ros_runtime import spin_node

SLOW_S = 4.0


class FaultyCorrector(CorrectorNode):
    def __init__(self) -> None:
        super().__init__()
        self._fault = ""
        correct, publish = self.stream.correct, self.pub_depth.publish

        def faulty_correct(*args: Any, **kwargs: Any) -> Any:
            if self._fault == "fault/pipeline":
                raise ZeroDivisionError("injected pipeline fault")
            if self._fault == "fault/slow":
                time.sleep(SLOW_S)
            return correct(*args, **kwargs)

        def faulty_publish(msg: Any) -> None:
            if self._fault == "fault/publish":
                raise RCLError("Failed to publish: injected publish fault")
            publish(msg)

        self.stream.correct = faulty_correct
        self.pub_depth.publish = faulty_publish

    def _process(self, pair: _Pair) -> Callable[[], None] | None:
        # the one worker thread alone reads it (its publish step runs before the next pair)
        self._fault = pair.depth.header.frame_id
        return super()._process(pair)


if __name__ == "__main__":
    sys.exit(spin_node(rclpy, FaultyCorrector, sys.argv[1:]))
