"""The ``corrector`` node executable (``ros2 run tof_mpd_ros corrector``)."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from .launch_args import node_parser, strip_ros_args

DESCRIPTION = (
    "Subscribes to ToF depth and amplitude images, removes multipath distortion (calibration, "
    "range-recovery net F, boundary nets G, geodesic filter) and publishes the corrected "
    "range image."
)


def main(args: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if args is None else args)
    parser = node_parser("corrector", DESCRIPTION)
    parser.parse_args(strip_ros_args(argv))
    print("corrector: not yet available in this version (the node is being built; see the README "
          "for what works today)", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main())
