"""Planar 7-link biped: robot description, floating-base simulator and the ROS 2 nodes around them."""
