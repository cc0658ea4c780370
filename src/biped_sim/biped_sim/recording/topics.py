"""The topic names of the biped's ROS 2 graph as plain strings (pure: no ROS import), so that readers of a
recorded bag (``bag_summary``) name topics without importing the ROS layer. ``biped_sim.graph.names``
re-exports them beside their message types and QoS profiles (the table in its docstring)."""
from __future__ import annotations

CLOCK = '/clock'
SIM_STATE = '/sim/state'
IMU = '/imu'
JOINT_STATES = '/joint_states'
GROUND_REACTION = '/ground_reaction'
GROUND_REACTION_COP = '/ground_reaction/cop'
STANCE = '/stance'
TF = '/tf'
ROBOT_DESCRIPTION = '/robot_description'
FALL = '/fall'
SIM_IMPACTS = '/sim/impacts'
SIM_PUSH = '/sim/push'
SIM_PLANT = '/sim/plant'
CONTROLLER_TORQUE = '/controller/torque'
CONTROLLER_STATUS = '/controller/status'
CONTROLLER_INFO = '/controller/info'
PUSH_EVENTS = '/push_events'
PUSH_REQUESTS = '/push_requests'
