"""The benchmark harness in quick mode (so it never rots: completes, writes well-formed JSON with the
expected keys; timings are never asserted), and exact-vs-PIQP agreement on seeded random instances
of the controller's shape (m = 20 rows) with degenerate rows mixed in: parallel / anti-parallel /
duplicated rows, zero-norm rows, rows scaled over many decades (N next to N m), feasible and
infeasible -- complementing tests/test_qp.py, which covers each degenerate case on its own."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from biped_controller.core.qp.solver import ACTIVE, INFEASIBLE_FALLBACK, UNCONSTRAINED, AdaptationQP
from biped_controller.core.qp.exact import solve_exact

ROOT = Path(__file__).resolve().parents[1]
from biped_controller.core.control.controller_layout import QP_ROWS

M = QP_ROWS  # rows of the controller's QP (17 with and 17 without the push estimate + 3 range rows)


@pytest.mark.slow
@pytest.mark.ros
def test_quick_benchmark_writes_json(tmp_path, ros_env):
    out = tmp_path / "results.json"
    sub = tmp_path / "sub"
    sub.mkdir()
    (sub / "wbc_step.json").write_text(json.dumps({"meta": {"date": "d0"}, "keys": {
        "controller.step_p50_us_wbc": 1.5, "controller.step_p50_us": -1.0}}))
    p = subprocess.run([sys.executable, "-m", "benchmarks.run", "--quick", "--json", str(out), "--sub-results", str(sub)],
                       cwd=ROOT, env=ros_env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    R = json.loads(out.read_text())
    assert set(R) >= {"meta", "targets", "hard_run", "controller", "solvers", "dds", "inprocess", "experiment",
                      "target_check"}
    pieces = R["controller"]["pieces_us"]
    for k in ("model_terms", "constraint_assembly", "qp_solve_all_steps", "total"):
        assert pieces[k]["n"] >= 300 and pieces[k]["p50"] > 0 and pieces[k]["p99"] >= pieces[k]["p50"]
    assert R["controller"]["replay_matches_run"] is True
    tab = R["solvers"]["table_us"]
    assert set(tab) == {"exact (qp_exact)", "PIQP held (AdaptationQP)", "PIQP via qpsolvers", "DAQP via qpsolvers",
                        "quadprog via qpsolvers", "OSQP via qpsolvers", "ProxQP via qpsolvers"}
    assert R["solvers"]["instances_constrained"] > 0
    for row in tab.values():
        assert {"p50", "p99", "failures", "ratio_to_fastest", "n"} <= set(row)
    assert tab["exact (qp_exact)"]["failures"] == 0
    assert {"pingpong", "lockstep"} <= set(R["dds"])
    assert "available" in R["dds"]["pingpong"] and "available" in R["dds"]["lockstep"]
    for engine in ("fast", "fast_outcome_only", "fast_objects", "reference", "mujoco"):
        for mode in ("none", "both"):
            assert R["inprocess"][engine][mode]["realtime_factor"] > 0
    keys = R["keys"]
    # a sub-benchmark's key is merged in, never over a key of this run
    assert keys["controller.step_p50_us_wbc"] == 1.5 and keys["controller.step_p50_us"] > 0
    assert R["merged"] == {"wbc_step.json": {"path": str(sub / "wbc_step.json"), "date": "d0",
                                             "keys": ["controller.step_p50_us_wbc"]}}
    assert set(keys) == {"controller.step_p50_us_wbc", "inprocess.fast.realtime_factor", "inprocess.reference.realtime_factor",
                         "inprocess.fast_outcome_only.realtime_factor", "controller.step_p50_us_reference_engine",
                         "controller.step_p50_us", "qp.early_out_p50_us", "qp.piqp_ratio_to_fastest",
                         "dds.lockstep_steps_per_s", "dds.pingpong_steps_per_s", "table.parallel_wall_s",
                         "dds.lockstep_with_recorder_steps_per_s", "sweep.map_full_wall_s", "sweep.sims_per_s",
                         "inprocess.mujoco.realtime_factor", "inprocess.mujoco.realtime_factor_cpu",
                         "inprocess.mujoco_over_fast_objects", "inprocess.mujoco_over_fast_objects_cpu"}
    for k in ("inprocess.fast.realtime_factor", "inprocess.reference.realtime_factor", "controller.step_p50_us",
              "inprocess.fast_outcome_only.realtime_factor", "controller.step_p50_us_reference_engine",
              "qp.early_out_p50_us", "qp.piqp_ratio_to_fastest", "sweep.sims_per_s", "inprocess.mujoco.realtime_factor",
              "inprocess.mujoco.realtime_factor_cpu", "inprocess.mujoco_over_fast_objects"):
        assert isinstance(keys[k], float) and keys[k] > 0, (k, keys[k])
    assert "available" in R["experiment"]
    assert keys["sweep.map_full_wall_s"] is None and R["sweep"]["quick"]       # --quick: a 2-phase map only
    assert R["sweep"]["simulations"] > 0
    md = (tmp_path / "results.md").read_text()
    assert "| solver |" in md and "| piece |" in md
    from biped_controller.studies.provenance import FIELDS, read_records
    recs = read_records(tmp_path)
    assert set(recs) == {"results.json", "results.md"}
    for rec in recs.values():
        assert set(FIELDS) <= set(rec) and rec["reconstructed"] is False
        assert rec["command"].startswith("python -m benchmarks.run --quick --json ")
        assert rec["duration_s"] > 0 and len(rec["load_average"]) == 3


# ------------------------------------------------------------------------------------------------
# exact 2-variable solver vs PIQP (AdaptationQP) on random instances with degenerate rows
# ------------------------------------------------------------------------------------------------

def _degenerate_instance(rng, feasible: bool):
    """Random rows through a random feasible point x0 (or not), then degenerate rows mixed in."""
    n = 2
    G = rng.normal(size=(M, n))
    x0 = rng.normal(scale=5.0, size=n)
    slack = rng.exponential(1.0, size=M) * rng.choice([0.0, 1.0], p=[0.2, 0.8], size=M)  # some rows tight at x0
    h = G @ x0 + slack
    kind = rng.integers(0, 5)
    i, j = rng.choice(M, size=2, replace=False)
    if kind == 0:                       # duplicated row (possibly rescaled)
        c = rng.uniform(0.1, 10.0)
        G[j], h[j] = c * G[i], c * h[i]
    elif kind == 1:                     # anti-parallel pair: a strip around x0
        G[j] = -rng.uniform(0.1, 10.0) * G[i]
        h[j] = G[j] @ x0 + rng.exponential(0.5)
    elif kind == 2:                     # zero-norm rows with h >= 0 (always satisfied)
        G[j] = 0.0
        h[j] = abs(h[j])
    elif kind == 3:                     # rows scaled over many decades (N vs N m)
        s = 10.0 ** rng.uniform(-3, 3, size=M)
        G, h = G * s[:, None], h * s
    else:                               # nearly parallel pair through x0
        G[j] = G[i] + 1e-7 * rng.normal(size=n)
        h[j] = G[j] @ x0
    # x* well outside so that some rows are active
    x_star = x0 + rng.normal(scale=20.0, size=n)
    if not feasible:
        # a row contradicting an existing one: g x <= h_i and -g x <= -h_i - d (d > 0)
        k = rng.choice([r for r in range(M) if r not in (i, j)])
        if np.linalg.norm(G[i]) == 0.0:
            G[i], h[i] = rng.normal(size=n), 0.0
        G[k] = -G[i]
        h[k] = -h[i] - rng.uniform(0.5, 5.0) * np.linalg.norm(G[i])
        if rng.random() < 0.3:          # or a zero-norm row with h < 0
            G[k], h[k] = 0.0, -1.0
    return G, h, x_star


@pytest.mark.parametrize("feasible", [True, False])
def test_exact_agrees_with_piqp_on_random_degenerate_instances(feasible):
    rng = np.random.default_rng(20260 + int(feasible))
    W = np.array([1.0, 1.0])
    held = AdaptationQP(2, M, W)
    statuses = []
    for _ in range(300):
        G, h, x_star = _degenerate_instance(rng, feasible)
        W = rng.uniform(0.1, 10.0, size=2)
        held.set_weights(W)
        ex = solve_exact(G, h, x_star, W)
        pq = held.solve(G, h, x_star)
        statuses.append(ex.status)
        if feasible:
            assert ex.status in (ACTIVE, UNCONSTRAINED)
        else:
            assert ex.status == INFEASIBLE_FALLBACK
        assert pq.status == ex.status, (pq.message, ex.message)
        scale = max(1.0, float(np.max(np.abs(ex.x))))
        assert np.max(np.abs(pq.x - ex.x)) <= 1e-6 * scale, (pq.x, ex.x, pq.message, ex.message)
        if ex.status == ACTIVE:   # both are feasible to rounding and equally good
            tol = 1e-9 * (np.abs(G) @ np.abs(ex.x) + np.abs(h) + 1.0)
            assert np.all(G @ pq.x - h <= 1e-6 * (np.abs(G) @ np.abs(pq.x) + np.abs(h) + 1.0))
            assert np.all(G @ ex.x - h <= tol)
    if feasible:
        assert statuses.count(ACTIVE) > 200


def test_exact_agrees_with_piqp_on_recorded_controller_instances():
    """QPs the controller built in a run pushed past the `both`-mode limit (falls): real scaling."""
    from biped_controller.core.control.config import load_controller_config
    from biped_controller.closed_loop.runner import run
    from biped_sim.plant.push import Push

    res = run(steps=1, mode="both", pushes=(Push(0.2315, 0.025, 150.0),), keep_qp=True)
    cfg = load_controller_config(mode="both")
    W = np.array([cfg.weight_p, cfg.weight_tau])
    held = AdaptationQP(2, M, W)
    n_con = 0
    for G, h, x_star, status in res.qp_instances:
        ex = solve_exact(G, h, x_star, W)
        pq = held.solve(G, h, x_star)
        assert pq.status == ex.status == status
        scale = max(1.0, float(np.max(np.abs(ex.x))))
        assert np.max(np.abs(pq.x - ex.x)) <= 1e-6 * scale
        n_con += status != UNCONSTRAINED
    assert n_con > 10


def _nonfinite_least_violation_cases():
    out = []
    for feasible in (True, False):
        rng = np.random.default_rng(20260 + int(feasible))
        for _ in range(300):
            G, h, x_star = _degenerate_instance(rng, feasible)
            W = rng.uniform(0.1, 10.0, size=2)
            ex = solve_exact(G, h, x_star, W)
            if not np.all(np.isfinite(ex.x)):
                out.append((G, h, x_star, W, ex.message))
    return out


def test_least_violation_is_finite_on_degenerate_instances():
    """A zero-norm row with h < 0 and rows spanning ~6 decades used to give x = NaN (fixed in
    qp_exact: minimum-norm Newton step on a numerically singular piece)."""
    bad = _nonfinite_least_violation_cases()
    assert not bad, f"{len(bad)} instance(s), e.g. {bad[0][4]}"


# ------------------------------------------------------------------------------------------ bench --controller
# scripts/bench as its user runs it (a subprocess from the repository root): no test imports benchmark code.
def _bench(*args: str, timeout: float = 600):
    return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout)


@pytest.mark.slow
def test_bench_controller_runs_the_plugin_bench(tmp_path):
    """``benchmarks.run --controller NAME --quick`` is the plug-in bench of NAME at 1 step, 1 repeat, written
    to --json (the plug-in bench's figures and keys, not the sections')."""
    out = tmp_path / "plugin.json"
    p = _bench("benchmarks.run", "--controller", "capture_point", "--quick", "--json", str(out))
    assert p.returncode == 0, p.stderr[-3000:]
    R = json.loads(out.read_text())
    assert (R["meta"]["steps"], R["meta"]["repeats"]) == (1, 1)
    assert "plugin_capture_point" in R["variants"] and R["keys"]["plugin.capture_point.realtime_factor"] > 0
    assert "controller" not in R and "hard_run" not in R


def test_bench_unknown_controller_is_an_error_naming_it():
    for mod in ("benchmarks.run", "benchmarks.plugin_bench"):
        p = _bench(mod, "--controller", "no_such_controller")
        assert p.returncode == 2 and "no_such_controller" in p.stderr, (mod, p.returncode, p.stderr[-2000:])
