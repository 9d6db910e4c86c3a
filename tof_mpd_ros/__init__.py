"""tof_mpd_ros: remove multipath distortion from Time-of-Flight range images on a robot arm.

The package is a functional core (pure numpy/torch modules under ``sim``, ``recordings``,
``collection``, ``correction``, ``training``, ``evaluation`` and ``mismatch``) with thin shells
on top (``nodes`` for ROS 2, ``cli`` for the ``tof-mpd`` command). Nothing outside ``nodes``
imports rclpy, and importing the package changes nothing in the process (the entry points choose
thread policies: :mod:`tof_mpd_ros.machine`).
"""

__version__ = "0.1.0"
