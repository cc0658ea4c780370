"""Push-recovery capability map: the survival boundary in force over onset phase x direction x duration,
for each adaptation mode, on a local process pool or a Ray cluster.

Run through ``scripts/capability_map [options]`` (``--help``); e.g. the default full map (4 modes x 2
directions x 20 phases x 3 durations) on two processes, resumable, with figures and a summary::

    scripts/capability_map --workers 2 --store build/capability_map/records.jsonl \\
        --out results/capability_map --json build/capability_map/summary.json

What one simulation is (:func:`simulate`, the pure task function every executor runs): the in-process
closed loop of ``trial.trials.survives`` (``runner.run``: Simulator + AdaptiveController, no ROS) with one
push of magnitude ``force`` [N] on the torso (``push_height`` of config/simulator.yaml unless
``--height``), horizontal, ``+`` forward (on the back) for direction ``forward`` and ``-`` for
``backward``, acting over [start, start + duration) [s] of simulated time.

Onset phase: a fraction ``phase`` in [0, 1) of the *first* step, ``start = phase * T`` [s], with T the
period of the preferred gait (``GaitFamily.T``, 0.463 s); the walk starts at t = 0 from the family's
initial state, the beginning of that first step (just after an impact). ``--phases N`` samples
``phase = k / N``, k = 0 .. N-1, so phase 0.5 is the paper's "middle of the first step"
(``trial.runs.DEFAULT_START``) whenever N is even. A long push may end after the first impact; survival
then counts the steps after the push's end. With the early stop (``trial.stop.EarlyStop`` on the rigid
plant, ``trial.stop.MujocoEarlyStop`` on MuJoCo, config/studies.yaml; ``--full-trials`` turns it off) a
trial back on the preferred gait one period after an impact after the push is decided there: survived,
the outcome of the full trial (measured).

Survival is the studies' one rule (``trial.survival``): no fall until ``SURVIVAL_STEPS`` impacts after
the end of the push, and p and tau' back within the band of the same settings' unpushed walk at the end
(never tighter than 1 mm and 1e-3; docs/experiments.md, "Survival").

Search per cell (mode, direction, phase, duration), as ``trial.search.max_push_modes`` does it for one
cell: the coarse forces ``trial.search.coarse_forces(max, coarse)`` (coarse, 2 coarse, ... <= max) are all
simulated, with ``max`` lowered to ``max_impulse / duration`` for long pushes (default 50 N s = 2000 N x
0.025 s: the same impulse range for every duration, 500 N at 0.1 s, 250 N at 0.2 s); ``trial.search.analyse_coarse`` gives the last survivable force below the first failing one
(lo, 0 when the first fails), the first failing coarse force (hi) and the survivable coarse forces above
it (the islands: survival is not monotone in the force); then [lo, hi] is bisected at midpoints down to
``resolution`` [N] (the midpoints of ``trial.search.bisect_edge``; tested equal). The boundary is the
largest survivable force below the lowest failing edge, known to within ``resolution``; a cell whose
coarse scan never fails is *censored* (boundary >= max). The search is a pure function of the records
of the cell (:func:`plan_cell`): it names the simulations still needed, so simulations of many cells run
in parallel and an interrupted map resumes from the records it stored. Once the boundary is known the
cell's *no-fall edge* (the largest force without a fall below the first fall) is searched to the same
resolution (:func:`~.search.plan_no_fall`: coarse forces upward from the first failing one to the first
fall, then the bisection).

Bracketed search (``search_from_neighbours`` of config/studies.yaml, ``--search
neighbours|full``): the first phase of each (mode, direction, duration) row is searched as above; every
other cell starts once its lower-phase neighbour's coarse edge is known, from that neighbour's lowest
failing coarse force k c: k c and the ``bracket_check_below`` (w) coarse forces under it, (k - 1) c ...
(k - w) c, are simulated; a failure among those under it moves the bracket down to the highest failing one,
a surviving k c moves it up one coarse step, until k c fails and the w under it survive; then [(k - 1) c,
k c] is bisected at the same midpoints (same boundary, first failure and cause as the full search
whenever no coarse force more than w steps under a survivable one between the edge and the hint fails:
the bracket checks w steps under itself as the island window checks above); above the edge coarse forces
are simulated until ``island_window`` consecutive ones fail (the islands found; ``Boundary.full`` False); a
bracket still surviving at the scan's top falls back to the full search (censored only if every coarse
force survives).

Each boundary force F [N] of a push of duration d [s] is also reported as
  * impulse ``I = F d`` [N s] (exact in the simulator: the force is constant on each integration
    interval, split at the push's start and end);
  * the change of the centre of mass's horizontal velocity the push alone causes,
    ``delta v_com = F d / M`` [m/s], M the robot's total mass from its description (momentum theorem on
    the whole robot with the push as the only external impulse; the ground reaction during the push is
    not counted, so this is a property of the push, comparable across robots);
  * a fraction of body weight ``F / (M g)`` [-] (g from the description), the convention of humanoid
    push-recovery test suites.
The failure cause is that of the first failing force after the bisection (hi): the simulator's fall
cause (``tip_toe``, ``tip_heel``, ``slip``, ``take_off``, ``no_liftoff``, ``numerical``; on MuJoCo
``body_contact``, ``hip_low``, ``foot_rotated``) or, without a fall, ``p_not_back`` / ``tau_dot_not_back``
(not back on the preferred gait), ``time_limit``, or ``controller_fault`` (a plug-in controller returned
what the plant cannot apply or raised: the trial is neither a survival nor a fall, its record's
``fault_kind`` names the fault, and where the lowest force that fell or faulted faulted the cell's no-fall
edge is undefined).

Records: one JSON object per simulation, one per line (JSON Lines), appended as each simulation
completes (:class:`RecordStore`); a rerun with the same store skips every simulation already stored for
the same *fingerprint* (sha256 of the controller and simulator settings, the robot description, the gait
family file, the survival rule (floors, band factor and window), the early stop and the push height; records of another fingerprint stay in the file
and are ignored). The code is not fingerprinted: after a change of the controller or the simulator that
changes results, start a new store (the summary records the git commit and the modified files). A torn last line (a run killed while writing) is cut
off. Each record carries the trial record's ``seed`` (the noise seed, null for a deterministic profile) and
``fault_kind`` (null, or the controller fault's kind; ``trial.record``), neither in its key nor in the
fingerprint: records of a store written before them are completed when loaded, and such a store resumes.
A notebook loads the file with ``load_records(path)`` or ``pandas.read_json(path, lines=True)``.

Executors: in-process (``--workers 1``), a local process pool (``--workers N``, default: all cores) or
Ray (``--ray``: a local Ray instance with ``num_cpus = --workers``; ``--ray ADDRESS``: an existing
cluster, whose nodes must have this package installed). All run the same :func:`simulate_batch` on
batches of ``--batch`` simulations (default 1 on the pool, 4 on Ray: a failing simulation takes ~0.1 s,
less than Ray's per-task overhead pays for). The simulator and the controller are deterministic, so every
executor gives the same records (tested).

Modules: ``spec`` (cells, search, map), ``metrics`` (conversions), ``task`` (one simulation and its
record), ``store`` (records, fingerprint), ``search`` (one cell's search), ``driver`` (``run_map``),
``executors`` (the shared ``closed_loop.executor`` bound to the task), ``findings`` (summary), ``figures``,
``cli``; ``studies.capability_map`` re-exports them (the public API and ``python -m``).

Pure: no ROS import.
"""
