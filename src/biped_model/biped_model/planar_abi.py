"""The constants of ``planar_kernels``' arrays and return codes, importable without compiling anything.

Pure Python, no numba. Joint kinds, the headers of the parameter arrays ``ti`` / ``tf``, the status
codes and the sizes of the kernels' small output arrays (see ``planar_kernels``' docstring for their
meaning); ``fast_engine`` builds the arrays with them, the kernels read them as compile-time constants.
"""
PX, PZ, REV = 0, 1, 2
HEADER_I = 5  # nj, nb, push_joint, foot_0, foot_1
HEADER_F = 3  # g, l_min, l_max
STATUS_OK = 0
STATUS_SINGULAR = 1
PROBE_SIZE = 3   # swing probe: lowest sole z [m], ankle z rate [m/s], lowest sole point z rate [m/s]
POINT_SIZE = 8   # point state: x, z, angle, vx, vz, omega, drift_x, drift_z
IMPACT_SIZE = 7  # impulse (3), old foot velocity (3), energy loss

# period outcome (``period``): completed, or handed back to the caller's event path untouched
PERIOD_DONE = 0
PERIOD_EVENT = 1
PERIOD_LIMITS_SIZE = 7   # mu, l_min, l_max, touchdown_tolerance, clearance, liftoff_penetration, cleared
PERIOD_OUT_SIZE = 4      # status, cleared after, push impulse [N s], interval of the event (-1: none)
