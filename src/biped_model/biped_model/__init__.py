"""The robot, shared by both sides (no ROS): description, gait family, the planar models (Pinocchio reference and
compiled twins), the contact rows, the config reader."""
