"""The ``corrector`` node (``ros2 run tof_mpd_ros corrector``).

Subscribes to ToF depth + amplitude images and CameraInfo, pairs them by stamp, corrects each pair
on a worker thread (bounded drop-oldest queue, so the subscription callbacks never do heavy work)
and publishes the corrected depth, G's edge map, a confidence image (with weights of the fcn
kind: the predicted sigma in metres, and an empty edge map), the cropped CameraInfo and
``/diagnostics``; while subscribed, organized point clouds of the corrected and the input depth
and the correction image. Parameters (but QoS) change at run time. Bad input (wrong encoding,
size mismatch, all-invalid frames, out-of-order stamps, a missing stream) is logged, counted by
reason and reported; the node keeps running.
"""

from __future__ import annotations

import sys
import warnings
from collections.abc import Sequence

from ..machine import SlowPrecisionWarning
from .ros_runtime import node_main

DESCRIPTION = (
    "Subscribes to ToF depth and amplitude images, removes multipath distortion (calibration, "
    "range-recovery net F, boundary nets G, geodesic filter; or, with weights of the fcn kind, "
    "one network that also predicts sigma) and publishes the corrected range image, an edge "
    "map, a confidence image (fcn kind: the predicted sigma in metres) and /diagnostics; while "
    "subscribed, point clouds of the corrected and the input depth and the correction image."
)


def main(args: Sequence[str] | None = None) -> int:
    # the node says this through its ROS logger (CorrectorNode._warn_adopted), not on stderr
    warnings.simplefilter("ignore", SlowPrecisionWarning)
    return node_main("corrector", DESCRIPTION, "corrector_node", "CorrectorNode", args)


if __name__ == "__main__":
    sys.exit(main())
