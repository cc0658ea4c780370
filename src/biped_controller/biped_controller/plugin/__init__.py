"""Bring your own controller: the controller interface (``interface``), what a controller knows of the robot
(``model``: the controller-side model, the gains and the reference with named fields, given with its
``ControllerSetup``), the registry of controllers by name (``registry``: built-in modes, ``biped.controllers``
entry points, ``module:Class``), the built-in modes as interface controllers (``builtin``: every consumer
reaches them through the interface; their compiled fast path is their own), the in-process closed loop that drives any of them on the
rigid or the MuJoCo plant (``loop``) and the run's result, the same type as the studies' ``runner.run``'s
(``result``); the push trials and the max-push search are the studies' (``studies.trial.plugin_trials``).
``python -m biped_controller.studies.controllers list | check NAME | max-push NAME`` (the CLI lives with the studies). Pure Python, no ROS."""
