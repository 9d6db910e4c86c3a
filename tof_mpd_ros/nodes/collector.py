"""The ``collector`` node executable (``ros2 run tof_mpd_ros collector``)."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from .launch_args import node_parser, strip_ros_args

DESCRIPTION = (
    "Drives a UR arm (ur_rtde or the simulated arm) through a viewpoint plan and records "
    "synchronised ToF, structured-light reference and arm poses to a rosbag2 MCAP recording."
)


def main(args: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if args is None else args)
    parser = node_parser("collector", DESCRIPTION)
    parser.parse_args(strip_ros_args(argv))
    print("collector: not yet available in this version (the node is being built; see the README "
          "for what works today)", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main())
