"""The simulated cell streaming ToF frames into the corrector.

    ros2 launch tof_mpd_ros sim_demo.launch.py rate_hz:=30.0
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    config = os.path.join(get_package_share_directory("tof_mpd_ros"), "config")
    return LaunchDescription([
        DeclareLaunchArgument("rate_hz", default_value="30.0"),
        Node(package="tof_mpd_ros", executable="sim_cell", name="sim_cell",
             parameters=[os.path.join(config, "sim_cell.yaml"),
                         {"rate_hz": LaunchConfiguration("rate_hz")}],
             output="screen"),
        # sim_cell publishes /tof/depth/image_raw, ... (relative names in the root namespace);
        # the corrector's relative inputs meet them in namespace tof.
        Node(package="tof_mpd_ros", executable="corrector", name="corrector", namespace="tof",
             parameters=[os.path.join(config, "corrector.yaml")], output="screen"),
    ])
