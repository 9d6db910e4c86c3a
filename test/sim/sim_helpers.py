"""Small, fast simulated-camera setups shared by the cell and dataset tests."""

from __future__ import annotations

import numpy as np

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.pose import make_pose
from tof_mpd_ros.sim.cell import CameraModel


def small_camera() -> CameraModel:
    """A 48x36 crop of a 120x90 sensor with the DS325's field of view: fast to render."""
    return CameraModel(sensor=Intrinsics.from_fov(120, 90, 74.0), crop=(48, 36), margin_px=4,
                       supersample=1)


def looking_down(height_mm: float) -> np.ndarray:
    """Camera above the base origin looking straight down (optical z = -base z), mm."""
    rot = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])
    return make_pose(rot, np.array([0.0, 0.0, height_mm]))
