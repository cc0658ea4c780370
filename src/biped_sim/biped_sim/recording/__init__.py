"""Recording: the rosbag2-layout MCAP writer (pure), the bag reader, the recorder node, the bag summary."""
