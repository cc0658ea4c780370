"""Studies (no ROS): what the product runs on the closed loop (``biped_controller.closed_loop``), each with its
one command. A new study goes here when a product command or a product test runs it; an investigation that
answers one question once goes to the repository's ``lab/`` (``lab/README.md``), which nothing here imports.

Product studies (``python -m biped_controller.studies.NAME``):

- ``experiment`` -- walk, push, max-push, table, probe, band (``scripts/experiment``), on ``single_runs``;
- ``capability_map`` -- the survival boundary over force x phase x direction x duration (``scripts/capability_map``;
  the package ``capmap/``);
- ``robustness`` -- the max-push table under plant perturbations (``scripts/robustness``);
- ``plant_compare`` -- walk, push and pushes on both plants side by side, and ``fingerprint``, the MuJoCo
  plant's records hashed (a behaviour check);
- ``fingerprint`` -- the rigid closed loop's records hashed (a behaviour check);
- ``fingerprint_record`` -- both fingerprints with the package versions that give them
  (``results/fingerprints/``);
- ``headline`` -- the README's headline table from the committed paper's-table files;
- ``baseline_wbc`` -- one push in modes none, wbc, both and hybrid: findings and figure;
- ``torso`` -- the torso parameter's cost and its p / tau' / lambda figure;
- ``controllers`` -- the registered controllers: list, check, their max-push rows and map slices;
- ``figures`` -- the gait family's figures (``scripts/figures``);
- ``robots`` -- a robot's life cycle: new, build, check, list (``scripts/robot``, ``docs/robots.md``).

Their shared pieces: ``trial/`` (settings, runs, the survival rule, the early stop, the push search, the
CLI flags), ``provenance`` (the record of each result file, ``results/README.md``).
"""
