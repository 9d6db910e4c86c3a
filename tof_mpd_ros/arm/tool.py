"""The tool on the UR5e's flange, as designed: the ToF camera and the structured-light sensor.

These nominal mounting transforms seed the planners (the viewpoint plans, the hand–eye plan)
and are the simulated cell's true ones by default; the hand–eye calibration
(:mod:`tof_mpd_ros.calibration.hand_eye`) measures the real ones.
"""

from __future__ import annotations

import numpy as np

from ..pose import make_pose

# (4, 4) ToF camera optical frame in the flange frame, metres: ~60 mm ahead of the flange,
# looking along the tool z axis (optical z = tool z).
DEFAULT_T_FLANGE_CAMERA_M = make_pose(np.eye(3), np.array([0.0, 0.0, 0.060]))


def default_sl_to_tof_mm() -> np.ndarray:
    """(4, 4) float64 SL camera optical frame in the ToF optical frame, mm: the SL camera 50 mm
    beside the ToF camera, optical axes parallel (a new array on every call)."""
    return make_pose(np.eye(3), np.array([-50.0, 0.0, 0.0]))
