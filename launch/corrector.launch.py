"""Run the corrector on a ToF camera's depth + amplitude topics.

    ros2 launch tof_mpd_ros corrector.launch.py depth_topic:=/camera/depth/image_raw
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    params = os.path.join(get_package_share_directory("tof_mpd_ros"), "config", "corrector.yaml")
    return LaunchDescription([
        DeclareLaunchArgument("depth_topic", default_value="/tof/depth/image_raw"),
        DeclareLaunchArgument("amplitude_topic", default_value="/tof/amplitude/image_raw"),
        DeclareLaunchArgument("camera_info_topic", default_value="/tof/camera_info"),
        Node(
            package="tof_mpd_ros",
            executable="corrector",
            name="corrector",
            parameters=[params, {
                "depth_topic": LaunchConfiguration("depth_topic"),
                "amplitude_topic": LaunchConfiguration("amplitude_topic"),
                "camera_info_topic": LaunchConfiguration("camera_info_topic"),
            }],
            output="screen",
        ),
    ])
