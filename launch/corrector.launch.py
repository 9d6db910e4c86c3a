"""Run the corrector on a ToF camera's depth + amplitude topics.

    ros2 launch tof_mpd_ros corrector.launch.py namespace:=camera \
        depth:=/camera/depth/image_rect amplitude:=/camera/ir/image_raw

The node's topics are relative (depth/image_raw, amplitude/image_raw, depth/camera_info in;
depth_corrected/image, ... out), so they follow `namespace`; the three input arguments are
remappings of its inputs (default: themselves, inside the namespace).
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
        DeclareLaunchArgument("namespace", default_value="tof"),
        DeclareLaunchArgument("depth", default_value="depth/image_raw"),
        DeclareLaunchArgument("amplitude", default_value="amplitude/image_raw"),
        DeclareLaunchArgument("camera_info", default_value="depth/camera_info"),
        Node(
            package="tof_mpd_ros",
            executable="corrector",
            name="corrector",
            namespace=LaunchConfiguration("namespace"),
            parameters=[params],
            remappings=[("depth/image_raw", LaunchConfiguration("depth")),
                        ("amplitude/image_raw", LaunchConfiguration("amplitude")),
                        ("depth/camera_info", LaunchConfiguration("camera_info"))],
            output="screen",
        ),
    ])
