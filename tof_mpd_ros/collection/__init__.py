"""Automatic data collection: viewpoint plans, resumable multi-part sessions, the capture loop.

Pure Python (no rclpy): the ``collector`` node supplies the arm (an
:class:`~tof_mpd_ros.arm.isolated.IsolatedArm`) and a capture function that reads topics.
"""
