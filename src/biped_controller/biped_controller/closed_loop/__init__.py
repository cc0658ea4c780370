"""The closed loop that every study runs on (no ROS): a plant and a controller stepped together, period by
period, in process (``runner``), its compiled segments on the rigid and the MuJoCo plant (``segment``,
``loop_kernels``, ``mujoco_loop_kernels``: internal speed-ups checked against the Python loop), and the
process pool that runs many closed loops at once (``executor``)."""
