"""The ``sim_cell`` node executable (``ros2 run tof_mpd_ros sim_cell``)."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from .launch_args import node_parser, strip_ros_args

DESCRIPTION = (
    "Publishes ToF depth/amplitude/CameraInfo and structured-light data from the simulated "
    "robotic cell."
)


def main(args: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if args is None else args)
    parser = node_parser("sim_cell", DESCRIPTION)
    parser.parse_args(strip_ros_args(argv))
    print("sim_cell: not yet available in this version (the node is being built; see the README "
          "for what works today)", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main())
