"""tof_mpd_ros: remove multipath distortion from Time-of-Flight range images on a robot arm.

The package is a functional core (pure numpy/torch modules under ``sim``, ``recordings``,
``collection``, ``correction``, ``training``, ``evaluation`` and ``mismatch``) with thin shells
on top (``nodes`` for ROS 2, ``cli`` for the ``tof-mpd`` command). Nothing outside ``nodes``
imports rclpy.
"""

import os

# numba's parallel kernels (geodesic filter, multipath) run on OpenMP; with the default active
# wait policy their idle threads spin and starve torch's threads in the same process (measured:
# a full correction 4x slower right after a geodesic call). Set before numba/torch load; an
# explicit user setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"
