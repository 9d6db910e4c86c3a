"""ROS 2 nodes: thin adapters between topics and the pure modules. Only this package imports
rclpy."""
