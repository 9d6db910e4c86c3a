"""The ``sim_cell`` node executable (``ros2 run tof_mpd_ros sim_cell``)."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from .ros_runtime import node_main

DESCRIPTION = (
    "Publishes ToF depth/amplitude/CameraInfo and structured-light data from the simulated "
    "robotic cell."
)


def main(args: Sequence[str] | None = None) -> int:
    return node_main("sim_cell", DESCRIPTION, "sim_cell_node", "SimCellNode", args)


if __name__ == "__main__":
    sys.exit(main())
