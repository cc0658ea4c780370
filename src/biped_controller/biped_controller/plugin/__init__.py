"""Bring your own controller: the controller interface (``interface``), the registry of controllers by
name (``registry``: built-in modes, ``biped.controllers`` entry points, ``module:Class``), the built-in
modes as interface controllers (``builtin``) and the in-process closed loop that drives any of them on
the rigid or the MuJoCo plant (``loop``). Pure Python, no ROS."""
