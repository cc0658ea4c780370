"""The studies' shared trial pieces (pure Python, no ROS), one concept per module:

- :mod:`.context`: the robot description, gait family and simulator settings loaded once per process;
- :mod:`.settings`: a run's settings (:class:`~.settings.RunSettings`: profile, ``--set`` overrides, plant
  perturbation) and their parsing;
- :mod:`.runs`: one closed-loop run with pushes (``runner.run`` with a run's settings), the paper's push;
- :mod:`.survival`: the survival rule of a pushed run;
- :mod:`.stop`: the early stop that decides a survival trial before its end;
- :mod:`.controller`: the one resolution step from a controller's name (built-in mode, registered
  controller, ``module:Class``) to the object every study calls (walk, band, verdict, survival trial);
- :mod:`.plugin_trials`: the survival trials and max-push search of an interface controller through the
  generic loop (``plugin.loop``);
- :mod:`.trials`: one survival trial (run + early stop + survival rule) of any controller;
- :mod:`.record`: the fields every trial record carries beside its outcome (``seed``, ``fault_kind``), and their
  completion in records stored before them;
- :mod:`.search`: the largest survivable push (coarse scan, bisection) and its table;
- :mod:`.summary`: the numbers of one run;
- :mod:`.args`: the command-line pieces every study's CLI shares (settings flags, checked value types).
"""
