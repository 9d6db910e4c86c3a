"""The ``corrector`` node (``ros2 run tof_mpd_ros corrector``).

Subscribes to ToF depth + amplitude images and CameraInfo, pairs them by stamp, corrects each pair
on a worker thread (bounded drop-oldest queue, so the subscription callbacks never do heavy work)
and publishes the corrected depth, G's edge map, a confidence image, the cropped CameraInfo and
``/diagnostics``. Bad input (wrong encoding, size mismatch, all-invalid frames, out-of-order stamps,
a missing stream) is logged, counted by reason and reported; the node keeps running.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from .launch_args import node_parser, strip_ros_args

DESCRIPTION = (
    "Subscribes to ToF depth and amplitude images, removes multipath distortion (calibration, "
    "range-recovery net F, boundary nets G, geodesic filter) and publishes the corrected range "
    "image, an edge map, a confidence image and /diagnostics."
)


def main(args: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if args is None else args)
    node_parser("corrector", DESCRIPTION).parse_args(strip_ros_args(argv))
    from ..errors import TofMpdError
    from .ros_runtime import spin_node

    try:
        import rclpy

        from .corrector_node import CorrectorNode

        return spin_node(rclpy, CorrectorNode, argv)
    except TofMpdError as err:
        print(f"corrector: cannot start: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
