"""The controller's ROS 2 node."""
