"""Studies (no ROS): the in-process closed loop, experiments, capability map, robustness, figures."""
