"""The controller core (no ROS, no plant): the adaptive controller, its QP and their compiled kernels."""
