"""Collect a labelled dataset: the simulated cell (or a real camera) plus the collector.

    ros2 launch tof_mpd_ros collector.launch.py arm_backend:=ur_rtde robot_ip:=192.168.1.10
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node


def generate_launch_description():
    config = os.path.join(get_package_share_directory("tof_mpd_ros"), "config")
    backend = LaunchConfiguration("arm_backend")
    return LaunchDescription([
        DeclareLaunchArgument("arm_backend", default_value="sim"),
        DeclareLaunchArgument("robot_ip", default_value="192.168.1.10"),
        DeclareLaunchArgument("recording_path", default_value="recordings/session"),
        Node(package="tof_mpd_ros", executable="sim_cell", name="sim_cell",
             parameters=[os.path.join(config, "sim_cell.yaml")], output="screen",
             condition=IfCondition(PythonExpression(["'", backend, "' == 'sim'"]))),
        Node(package="tof_mpd_ros", executable="collector", name="collector",
             parameters=[os.path.join(config, "collector.yaml"), {
                 "arm_backend": backend,
                 "robot_ip": LaunchConfiguration("robot_ip"),
                 "recording_path": LaunchConfiguration("recording_path"),
             }],
             output="screen"),
    ])
