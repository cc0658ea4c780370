"""Fast build of a gait family: the algorithm of :func:`generation.generate` on both cores.

    python -m biped_controller.gaits.build --out FILE [--settings YAML] [--workers N] [--check]

Same steps as ``generate`` (p_d from the stated initial guess, the two warm-started chains outwards, the
continuation sweeps, the smoothing passes, the fit and its range, the held-out strides, the 1 m/s
question, the validation), with five differences in how they are computed, none in what is computed:

* **single-threaded BLAS** in every process (:mod:`.blas`): SLSQP's subproblem goes through OpenBLAS,
  whose multi-threaded result differs in the last bits from the single-threaded one, and two
  OpenBLAS threads on a shared 2-core machine are several times slower than one;
* **independent solves in worker processes**: the two chains (up and down from p_d), the strides of
  one smoothing pass (independent given the pass's fit), the held-out strides, the 1 m/s sweep, and
  the probes of the fitted family. Each task's result depends on its inputs alone, so the file is the
  same bit for bit for any number of workers (``--workers 1`` runs everything in this process);
* **speculative continuation sweeps**: a sweep is sequential (stride b is warm-started from the current
  answer at its neighbour a); while b is solved, the next stride is solved from the current answer at
  b, and that guess is kept only if b's answer was not replaced (it rarely is after the first sweep),
  so the sweep gives exactly the sequential result;
* **diagnostics only for the solutions kept** (``StepOptimizer.diagnose`` depends on the solution
  alone): candidates rejected by a sweep are not diagnosed;
* **no solve made twice** (:class:`SolveMemo`): a sweep's solve with the same stride and warm start as an
  earlier one (the chain's, or the previous sweep's) is that solve's stored result (``--no-memo``: solved
  again; the same file).

The default ``--evaluator fast`` also uses :class:`.fast_eval.FastStepOptimizer` (exact derivative of the
impact map with respect to the pre-impact velocities, on which it is linear, instead of central
differences; the grid terms batched): a different (more exact) gradient, so its family differs from
the reference evaluator's within the fit tolerances, not bit for bit; ``--evaluator reference`` gives
``generate``'s numbers under single-threaded BLAS.
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import multiprocessing as mp
import pickle
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from biped_model.settings import default_robot_dir

from biped_controller.gaits.blas import blas_info, set_blas_threads
from biped_controller.gaits.optimizer import GaitSettings, StepOptimizer, StepSolution, load_gait_settings

EVALUATORS = ("fast", "reference")

# ------------------------------------------------------------------ worker side
_W: dict = {}


def _make_optimizer(desc, st: GaitSettings, evaluator: str) -> StepOptimizer:
    if evaluator == "fast":
        from biped_controller.gaits.fast_eval import FastStepOptimizer
        return FastStepOptimizer(desc=desc, settings=st)
    if evaluator == "reference":
        return StepOptimizer(desc=desc, settings=st)
    raise ValueError(f"evaluator must be one of {EVALUATORS}, got {evaluator!r}")


def _init(desc, st: GaitSettings, evaluator: str) -> None:
    set_blas_threads(1)
    _W["desc"], _W["st"], _W["evaluator"] = desc, st, evaluator
    _W["opt"] = _make_optimizer(desc, st, evaluator)


def _solve(p: float, c0, target, weight: float, diagnose: bool) -> StepSolution:
    return _W["opt"].solve(p, c0=c0, target=target, weight=weight, diagnose=diagnose)


def _chain(strides: list[float], c_start: np.ndarray) -> tuple[list[StepSolution], list[tuple]]:
    """``generation.solve_family``'s chain: each stride warm-started from the last successful one,
    retried once from the stated initial guess when it fails. Returns the chain's solutions and, for
    :class:`SolveMemo`, each warm-started solve as ``(key, solution)`` (``_solve``'s key)."""
    opt = _W["opt"]
    out, prev, solved = [], c_start, []
    for s in strides:
        sol = opt.solve(s, c0=prev, diagnose=False)
        solved.append((solve_key(s, prev, None, 0.0, False), sol))
        if not sol.success:
            alt = opt.solve(s, diagnose=False)
            if alt.success and (not sol.success or alt.criterion < sol.criterion):
                sol = alt
        out.append(sol)
        if sol.success:
            prev = sol.c
    return out, solved


def _diagnose(sol: StepSolution) -> StepSolution:
    _W["opt"].diagnose(sol)
    return sol


def _speed(strides: list[float], v: float, warm: np.ndarray) -> dict:
    from biped_controller.gaits.generation import speed_question
    opt = _make_optimizer(_W["desc"], _W["st"], _W["evaluator"])  # speed_question changes T: its own optimizer
    return speed_question(opt, strides, v, warm, progress=False)


def _probe(fam, ps: list[float]) -> list[dict]:
    from biped_controller.gaits.generation import probe_family
    return [probe_family(fam, p, _W["opt"]) for p in ps]


def solve_key(p: float, c0, target, weight: float, diagnose: bool) -> tuple:
    """What a ``_solve`` depends on: the stride, the warm start, the smoothing target and weight, whether it is
    diagnosed (the optimiser's description and settings are the build's own, the same for every task)."""
    def b(x):
        return None if x is None else np.ascontiguousarray(x, dtype=float).ravel().tobytes()
    return float(p), b(c0), b(target), float(weight), bool(diagnose)


class SolveMemo:
    """The solves already asked for in this build, by :func:`solve_key`.

    A solve is a function of its inputs alone (each task's result depends on them alone, which is also why
    the file is the same for any number of workers), so a solve asked again with the same inputs returns the
    stored :class:`StepSolution` instead of running SLSQP again: the same object, the same bits. The
    continuation sweeps ask for such solves: the first sweep's pass in a chain's own direction re-solves
    each stride from the very neighbour the chain solved it from, and the last sweep (the one that changes
    nothing) repeats the previous sweep's solves wherever the neighbour did not change since. Entries are
    futures (a solve still running is not submitted twice)."""

    def __init__(self):
        self.store: dict[tuple, object] = {}
        self.hits = 0
        self.misses = 0

    def get(self, key: tuple):
        fut = self.store.get(key)
        if fut is not None:
            self.hits += 1
        return fut

    def put(self, key: tuple, fut) -> object:
        self.store[key] = fut
        return fut


class _Done:
    def __init__(self, value):
        self._v = value

    def result(self):
        return self._v


class Runner:
    """Runs the tasks above in ``workers`` spawned processes (or in this process when ``workers`` is 1)."""

    def __init__(self, workers: int, desc, st: GaitSettings, evaluator: str, memo: bool = True):
        self.workers = max(1, int(workers))
        self.memo = SolveMemo() if memo else None
        if self.workers > 1:
            set_blas_threads(1)  # before spawning: OPENBLAS_NUM_THREADS=1 for the children too
            self.ex = ProcessPoolExecutor(self.workers, mp_context=mp.get_context("spawn"), initializer=_init,
                                          initargs=(desc, st, evaluator))
        else:
            self.ex = None
            _init(desc, st, evaluator)

    def submit(self, fn, *args):
        return self.ex.submit(fn, *args) if self.ex is not None else _Done(fn(*args))

    def solve(self, p: float, c0, target, weight: float, diagnose: bool):
        """``submit(_solve, ...)`` through the memo (``memo`` None: always solved)."""
        if self.memo is None:
            return self.submit(_solve, p, c0, target, weight, diagnose)
        key = solve_key(p, c0, target, weight, diagnose)
        fut = self.memo.get(key)
        if fut is None:
            self.memo.misses += 1
            fut = self.memo.put(key, self.submit(_solve, p, c0, target, weight, diagnose))
        return fut

    def map(self, fn, arglists: list[tuple]) -> list:
        return [f.result() for f in [self.submit(fn, *a) for a in arglists]]

    def probe_many(self, fam, ps: list[float]) -> list[dict]:
        """``[probe_family(fam, p, opt) for p in ps]`` in ``workers`` contiguous slices."""
        k = self.workers
        cuts = [round(i * len(ps) / k) for i in range(k + 1)]
        parts = self.map(_probe, [(fam, ps[cuts[i]:cuts[i + 1]]) for i in range(k) if cuts[i + 1] > cuts[i]])
        return [r for part in parts for r in part]

    def close(self) -> None:
        if self.ex is not None:
            self.ex.shutdown(wait=True)
            self.ex = None


# ------------------------------------------------------------------ the build
def _log(progress: bool, t0: float, msg: str) -> None:
    if progress:
        sys.stderr.write(f"[{time.perf_counter() - t0:6.1f} s] {msg}\n")
        sys.stderr.flush()


def _sweep_pass(run: Runner, out: dict[float, StepSolution], order: list[float]) -> int:
    """One pass of ``generation.solve_family``'s continuation sweep over ``order``, speculating one stride
    ahead; the same result as the sequential pass."""
    changed = 0
    spec: dict[int, tuple[StepSolution, object]] = {}
    for k in range(len(order) - 1):
        a, b = order[k], order[k + 1]
        if not out[a].success:
            spec.pop(k, None)
            continue
        src, fut = spec.pop(k, (None, None))
        if src is not out[a]:
            fut = run.solve(b, out[a].c, None, 0.0, False)
        if k + 1 < len(order) - 1 and out[b].success and run.workers > 1:
            spec[k + 1] = (out[b], run.solve(order[k + 2], out[b].c, None, 0.0, False))
        cand = fut.result()
        if cand.success and (not out[b].success or cand.criterion < out[b].criterion - 1e-6 * abs(out[b].criterion)):
            out[b] = cand
            changed += 1
    for _, fut in spec.values():
        fut.result()
    return changed


#: the modules whose code decides a build's numbers: a checkpoint written by other code is not resumed
_CODE = ("optimizer.py", "fast_eval.py", "build.py", "generation.py")


def checkpoint_path(out: Path) -> Path:
    """Where a build writing ``out`` keeps its checkpoint: ``.<name>.resume.pkl`` beside it (git ignores it)."""
    out = Path(out)
    return out.with_name(f".{out.name}.resume.pkl")


def checkpoint_key(desc, st: GaitSettings, evaluator: str, first_guess, max_sweeps: int) -> str:
    """sha256 of what the build's numbers depend on: the description, the gait settings (values, not their
    reasons), the evaluator, p_d's first guess, the sweep cap and the code of :data:`_CODE` (not the number of
    worker processes, which changes nothing)."""
    h = hashlib.sha256()
    h.update(pickle.dumps((desc, dataclasses.replace(st, raw=None), evaluator,
                           None if first_guess is None else np.asarray(first_guess, dtype=float).tobytes(),
                           int(max_sweeps)), protocol=4))
    here = Path(__file__).resolve().parent
    for name in _CODE:
        h.update((here / name).read_bytes())
    return h.hexdigest()


class _Checkpoint:
    """The build's state at the end of a phase (after p_d and the chains, after each continuation sweep,
    after each smoothing pass): ``{"key", "phase", "index", "changed", "sols"}`` pickled to ``path`` through
    a temporary file and a rename, so an interruption leaves the last complete phase. Every solve is a function
    of its inputs alone, so a build resumed from a phase's state writes the same file, bit for bit, as one
    that was never interrupted (``tests/test_gait_build.py``). ``path`` None: no checkpoint."""

    def __init__(self, path: Path | None, key: str):
        self.path, self.key = (None if path is None else Path(path)), key

    def load(self) -> dict | None:
        """The stored state when it was written for this key, else None (a stale file is left to be replaced)."""
        if self.path is None or not self.path.exists():
            return None
        try:
            with open(self.path, "rb") as f:
                state = pickle.load(f)
        except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ValueError):
            return None
        return state if isinstance(state, dict) and state.get("key") == self.key else None

    def save(self, phase: str, index: int, changed: int, sols: dict) -> None:
        if self.path is None:
            return
        tmp = self.path.with_name(self.path.name + ".tmp")
        with open(tmp, "wb") as f:
            pickle.dump({"key": self.key, "phase": phase, "index": index, "changed": changed, "sols": dict(sols)},
                        f, protocol=4)
        tmp.replace(self.path)

    def remove(self) -> None:
        if self.path is not None:
            self.path.unlink(missing_ok=True)


def build_family(st: GaitSettings, desc=None, workers: int = 2, evaluator: str = "fast", progress: bool = True,
                 speed: bool = True, max_sweeps: int = 4, first_guess: np.ndarray | None = None,
                 memo: bool = True, checkpoint: Path | None = None) -> tuple[dict, dict]:
    """The family file's contents (as ``generation.generate`` writes them) and the build's timings (and the
    memo's counts: ``sweep_solves`` run, ``sweep_memo_hits``); ``first_guess``: the normalised coefficients p_d's
    solve starts from (None: the stated initial guess); ``memo``: reuse the continuation sweeps' repeated solves
    (:class:`SolveMemo`; False: solve each again, as before it; the same file either way); ``checkpoint``: a
    file (:func:`checkpoint_path`) holding the state after each phase; a build finding one written for the same
    inputs (:func:`checkpoint_key`) resumes after its phase, and removes it when the family is complete."""
    from biped_controller.gaits.generation import (_fit_from_solutions, _solution_record, _validate, fit_and_restrict,
                                                   restrict_to_held_out)
    set_blas_threads(1)
    t0 = time.perf_counter()
    times: dict[str, float] = {}
    opt = _make_optimizer(desc, st, evaluator)
    ck = _Checkpoint(checkpoint, checkpoint_key(opt.desc, st, evaluator, first_guess, max_sweeps))
    state = ck.load()
    run = Runner(workers, opt.desc, st, evaluator, memo=memo)
    try:
        p_d = st.p_d
        if state is None:
            # 1. p_d from the stated initial guess, then the two chains outwards (independent of each other)
            sols: dict[float, StepSolution] = {p_d: run.submit(_solve, p_d, first_guess, None, 0.0, False).result()}
            up = sorted(s for s in st.strides if s > p_d)
            down = sorted((s for s in st.strides if s < p_d), reverse=True)
            fu, fd = run.submit(_chain, up, sols[p_d].c), run.submit(_chain, down, sols[p_d].c)
            for chain, fut in ((up, fu), (down, fd)):
                chain_sols, solved = fut.result()
                sols.update(zip(chain, chain_sols))
                if run.memo is not None:
                    for key, sol in solved:
                        run.memo.put(key, _Done(sol))
            ck.save("chains", 0, -1, sols)
            _log(progress, t0, f"p_d and the two chains: {sum(s.success for s in sols.values())}/{len(sols)} feasible")
        else:
            sols = dict(state["sols"])
            _log(progress, t0, f"resumed from {ck.path} (after {state['phase']} {state['index'] + 1})")
        times["chains"] = time.perf_counter() - t0
        # 2. continuation sweeps (none left when resumed after the last one, or in the smoothing)
        ps = sorted(sols)
        first_sweep = 0 if state is None or state["phase"] == "chains" else state["index"] + 1
        if state is not None and (state["phase"] == "smooth" or state["changed"] == 0):
            first_sweep = max_sweeps
        for sweep in range(first_sweep, max_sweeps):
            changed = _sweep_pass(run, sols, ps) + _sweep_pass(run, sols, ps[::-1])
            ck.save("sweep", sweep, changed, sols)
            _log(progress, t0, f"continuation sweep {sweep + 1}: {changed} strides improved")
            if changed == 0:
                break
        times["sweeps"] = time.perf_counter() - t0 - times["chains"]
        if run.memo is not None:
            times["sweep_solves"], times["sweep_memo_hits"] = run.memo.misses, run.memo.hits
        # the 1 m/s question needs p_d only (never changed by the smoothing): runs beside the smoothing
        fut_speed = run.submit(_speed, [0.35, 0.40, 0.45, 0.50, 0.55, 0.60, 0.65], 1.0, sols[p_d].c) if speed else None
        # 3. smoothing passes: the strides of one pass are independent given the pass's fit
        scale = st.T ** np.arange(5)[None, :]
        first_pass = state["index"] + 1 if state is not None and state["phase"] == "smooth" else 0
        for it, w in enumerate(st.smoothing_weights):
            if it < first_pass:
                continue
            fam = _fit_from_solutions(sols, st)
            todo = [p for p in sorted(sols) if p != p_d and sols[p].success]
            tg = [fam.coefficients(p)[0] * scale for p in todo]
            res = run.map(_solve, [(p, t, t, w, False) for p, t in zip(todo, tg)])
            changed = 0
            for p, cand in zip(todo, res):
                if cand.success:
                    sols[p] = cand
                    changed += 1
            ck.save("smooth", it, changed, sols)
            _log(progress, t0, f"smoothing pass {it + 1} (weight {w:g}): {changed} strides re-solved")
        t_s = time.perf_counter()
        # 4. diagnostics of the strides kept
        ps = sorted(sols)
        for p, sol in zip(ps, run.map(_diagnose, [(sols[p],) for p in ps])):
            sols[p] = sol
        records = [_solution_record(sols[p]) for p in ps]
        # 5. fit, range, held-out strides (independent given the fit), range narrowed to where they pass
        fam = fit_and_restrict(records, st, opt, probe_many=run.probe_many)
        lo, hi = fam.meta["fit_range"]
        used = [r["stride"] for r in records if lo <= r["stride"] <= hi]
        w = st.smoothing_weights[-1]
        mids = [0.5 * (a + b) for a, b in zip(used[:-1], used[1:])]
        tg = [fam.coefficients(p)[0] * scale for p in mids]
        held = run.map(_solve, [(p, t, t, w, True) for p, t in zip(mids, tg)])
        fam = restrict_to_held_out(fam, used, held, st)
        _log(progress, t0, f"held-out strides: {sum(h.success for h in held)}/{len(held)} feasible; "
                           f"range [{fam.p_min}, {fam.p_max}]")
        speed_rec = fut_speed.result() if fut_speed is not None else None
        times["family"] = time.perf_counter() - t0
        data = {
            "description": "Reference gait family q_d(p, tau) of the planar biped; built by biped_controller.gaits.build",
            "family": fam.to_dict(),
            "settings": dict(st.raw),
            "solver": {"name": "scipy.optimize.minimize(method='SLSQP')",
                       "gradients": ("exact (Pinocchio RNEA derivatives) on the grid; impact map: exact in the "
                                     "pre-impact velocities, central differences in the configuration"
                                     if evaluator == "fast" else
                                     "exact (Pinocchio RNEA derivatives) on the grid; central differences of the "
                                     "impact map at the end of the step"),
                       "initial_guess": "double-support postures at both ends, linear interpolation + swing-knee bump (StepOptimizer.initial_guess), for p_d; neighbours warm-started",
                       "build": f"biped_controller.gaits.build, evaluator {evaluator}, single-threaded BLAS"},
            "strides": records,
            "held_out": [dict(_solution_record(h), smoothing_weight=w) for h in held],
        }
        if speed_rec is not None:
            data["speed_1mps"] = speed_rec
        # 6. validation (probes in the workers)
        data["validation"] = _validate(fam, data, opt, probe_many=run.probe_many)
        times["after_smoothing"] = time.perf_counter() - t_s
        times["total"] = time.perf_counter() - t0
        _log(progress, t0, "validated")
        ck.remove()
    finally:
        run.close()
    return data, times


def write_settings(path: Path, base: Path | None = None, reason: str = "reduced family (tests, quick bench)",
                   **values) -> Path:
    """A gait settings file: ``base`` (default robots/biped7/gait.yaml) with the ``values`` given (keys of the
    file, e.g. ``strides``, ``smoothing_breakpoints``, ``smoothing_weights``) replaced, each with ``reason``."""
    import yaml
    from biped_model.settings import load_yaml_tree
    tree = load_yaml_tree(base if base is not None else default_robot_dir() / "gait.yaml")
    for k, v in values.items():
        if k not in tree:
            raise KeyError(f"unknown gait setting {k!r}")
        tree[k] = {"value": v, "reason": reason}
    path = Path(path)
    path.write_text(yaml.safe_dump(tree, sort_keys=False), encoding="utf-8")
    return path


#: A reduced family around p_d: 6 strides, 4 smoothing breakpoints, 2 smoothing passes (tests, --quick).
REDUCED = {"strides": [0.4375, 0.45, 0.463, 0.475, 0.4875, 0.5],
           "smoothing_breakpoints": [0.4375, 0.463, 0.4875, 0.5],
           "smoothing_weights": [1.0, 1.0e4]}


def write_family(data: dict, path: Path) -> None:
    """The file as ``generate`` writes it (sorted keys, indent 1), through a temporary file and a rename."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    tmp.replace(path)


def main(argv: list[str] | None = None) -> int:
    from biped_controller.gaits.generation import print_report, within_tolerance
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True, help="family file to write (never the committed one by default)")
    ap.add_argument("--settings", type=Path, default=None, help="gait settings (default robots/biped7/gait.yaml)")
    ap.add_argument("--workers", type=int, default=2, help="worker processes (1: everything in this process; same file)")
    ap.add_argument("--evaluator", choices=EVALUATORS, default="fast")
    ap.add_argument("--no-speed", action="store_true", help="skip the 1 m/s question")
    ap.add_argument("--no-memo", action="store_true",
                    help="solve the continuation sweeps' repeated solves again (the build before SolveMemo; same file)")
    ap.add_argument("--robot", default=None, metavar="NAME|PATH",
                    help="the robot (a name under robots/ or a robot directory; default biped7): its description and "
                         "its gait.yaml (unless --settings); scripts/robot build writes a robot's own family")
    args = ap.parse_args(argv)
    from biped_model.robot import RobotError, resolve_robot
    try:
        robot = resolve_robot(args.robot)
        desc = robot.description()
    except RobotError as exc:
        print(f"build: error: {exc}", file=sys.stderr)
        return 2
    if args.settings is None and not robot.is_default:
        args.settings = robot.gait_path
    st = load_gait_settings(args.settings) if args.settings else load_gait_settings()
    if args.out.resolve() == (default_robot_dir() / "gait_family.json").resolve():
        print("build: refusing to overwrite the committed family; give another --out", file=sys.stderr)
        return 2
    data, times = build_family(st, desc=None if robot.is_default else desc, workers=args.workers,
                               evaluator=args.evaluator, speed=not args.no_speed, memo=not args.no_memo,
                               checkpoint=checkpoint_path(args.out))
    if not robot.is_default:          # the stamp as generation.generate writes it (biped_model.robot)
        from biped_model.robot import STAMP_KEY, description_hash
        data[STAMP_KEY] = {"description_sha256": description_hash(desc)}
    write_family(data, args.out)
    print_report(data, data["validation"])
    print("times [s]: " + ", ".join(f"{k} {v:.1f}" for k, v in times.items()) + f"; BLAS {blas_info()}")
    ok, why = within_tolerance(data["validation"], st)
    for w in why:
        print(f"NOT ACCEPTED: {w}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
