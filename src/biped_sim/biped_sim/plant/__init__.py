"""The plant (no ROS): the ``Plant`` protocol and its engines (rigid), pushes, perturbations and sensing."""
