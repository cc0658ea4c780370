"""The controller core (no ROS, no plant): the adaptive controller, its QP and the controller's view of the
robot from real sensing, each with its compiled (numba) twin.

Rooms, each importing only the rooms listed before it (checked by ``tests/test_layout.py``):

* ``qp``      -- the adaptation QP: its problem, results and statuses (``problem``), the exact solver for
                 n <= 2 (``exact``), the PIQP-held solver and the least-violation fallback (``solver``).
* ``sensing`` -- the joint-state estimator (``estimation``), the generalized-momentum observer
                 (``momentum_observer``), the legs' model error identified from it (``model_error``), the
                 Smith predictor (``predictor``), the touchdown band (``touchdown_band``) and the per-period
                 pipeline that chains them (``pipeline``).
* ``control`` -- the p/tau-adaptive controller (``controller``) with its per-period arrays, and the
                 whole-body stage of its ``wbc`` / ``hybrid`` modes (``wbc``).

Naming rule for a Python reference and its compiled twin, inside one room:

* ``<name>.py``          -- Python (NumPy / Pinocchio): the reference and the tests' oracle; it loads its
                            kernels (through ``biped_model.numba_cache.load``).
* ``<name>_kernels.py``  -- the numba twin: the same equations, units and row order, compiled; a kernel
                            module is imported only through ``numba_cache.load``, never directly.
* ``<name>_layout.py``   -- the flat float64 arrays that ``<name>`` and ``<name>_kernels`` share, declared
                            once (``biped_model.layout.Layout``).
* ``<name>_compiled.py`` -- a Python class with ``<name>``'s interface that runs ``<name>_kernels``, when
                            ``<name>.py`` does not host that engine itself.

So ``qp/exact.py`` / ``qp/exact_kernels.py``, ``control/controller.py`` / ``controller_kernels.py`` /
``controller_layout.py``, ``control/wbc.py`` / ``wbc_kernels.py``, ``sensing/model_error.py`` /
``model_error_kernels.py``, ``sensing/pipeline.py`` / ``pipeline_compiled.py`` / ``pipeline_kernels.py`` /
``pipeline_layout.py``.
"""
