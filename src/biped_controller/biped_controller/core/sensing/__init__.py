"""The controller's view of the robot from real sensing: joint-state estimator, generalized-momentum
observer, the legs' model error, Smith predictor, touchdown band, and the per-period pipeline chaining them
(``pipeline``; compiled: ``pipeline_compiled`` on ``pipeline_kernels`` and ``model_error_kernels``).
Imports the ``qp`` room only (the touchdown band's least-violation torque)."""
