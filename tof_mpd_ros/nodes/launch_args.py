"""Command-line handling shared by the node executables (before rclpy starts)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence


def strip_ros_args(argv: Sequence[str]) -> list[str]:
    """Drop ``--ros-args ... [--]`` so argparse sees only the node's own options."""
    out: list[str] = []
    in_ros = False
    for token in argv:
        if token == "--ros-args":
            in_ros = True
        elif in_ros and token == "--":
            in_ros = False
        elif not in_ros:
            out.append(token)
    return out


def node_parser(prog: str, description: str) -> argparse.ArgumentParser:
    """An argparse parser for a node executable; ROS arguments follow ``--ros-args``."""
    return argparse.ArgumentParser(
        prog=prog, description=description,
        epilog="ROS arguments (parameters, remapping) go after --ros-args, e.g. "
               f"`ros2 run tof_mpd_ros {prog} --ros-args --params-file config/{prog}.yaml`.")
