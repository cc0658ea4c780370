"""The ROS 2 graph's plumbing on the plant side: names, parameters, nodes, launcher, demo, soak."""
