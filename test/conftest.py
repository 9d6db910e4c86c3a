"""Test-wide setup: keep every ROS process on loopback with its own domain, before rclpy loads."""

from __future__ import annotations

import os
import tempfile

# DDS discovery must never leave loopback on this machine; a private domain keeps parallel runs
# apart. These must be set before rclpy is imported anywhere in the test session.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", "37")
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="tof_mpd_ros_log_"))
os.environ.setdefault("HOME", tempfile.gettempdir())
os.environ.setdefault("MPLBACKEND", "Agg")

try:  # keep the 2-core machine usable by parallel test processes
    import torch

    torch.set_num_threads(1)
except ImportError:  # pragma: no cover - torch is a hard dependency, but keep conftest robust
    pass
