"""The ``collector`` node executable (``ros2 run tof_mpd_ros collector``)."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from .ros_runtime import node_main

DESCRIPTION = (
    "Drives a UR arm (ur_rtde or the simulated arm) through a viewpoint plan and records "
    "synchronised ToF, structured-light reference and arm poses to a rosbag2 MCAP recording."
)


def main(args: Sequence[str] | None = None) -> int:
    return node_main("collector", DESCRIPTION, "collector_node", "CollectorNode", args)


if __name__ == "__main__":
    sys.exit(main())
