"""The fast build of a gait family (biped_controller.gaits.build): the same numbers for any number of
worker processes, the reference evaluator giving the generator's own numbers, the fast evaluator's values
and gradients against the reference's, BLAS thread control. Reduced families (a few strides around p_d,
one or two smoothing passes); no timing here (speed: benchmarks/gait_build.py, results/gait_build/).
"""
from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from helpers import ROOT

from biped_controller.gaits.blas import blas_info, set_blas_threads
from biped_controller.gaits.build import REDUCED, build_family
from biped_controller.gaits.fast_eval import FastStepOptimizer, compare_evaluations
from biped_controller.gaits.generation import _solution_record, smooth_family, solve_family
from biped_controller.gaits.optimizer import StepOptimizer, load_gait_settings

# the fewest strides a family takes (a not-a-knot spline needs four breakpoints), p_d among them
FOUR = [0.45, 0.463, 0.475, 0.4875]
FAMILY = json.loads((ROOT / "robots" / "biped7" / "gait_family.json").read_text(encoding="utf-8"))


def _reduced(**kw):
    st = load_gait_settings()
    vals = dict(REDUCED, **kw)
    return dataclasses.replace(st, strides=tuple(vals["strides"]), smoothing_breakpoints=tuple(vals["smoothing_breakpoints"]),
                               smoothing_weights=tuple(vals["smoothing_weights"]))


@pytest.fixture(autouse=True, scope="module")
def _restore_blas_threads():
    """These tests set OpenBLAS to one thread (as the build does); the rest of the suite gets back the
    count it had, and the environment variable as it was."""
    before = [r.get("threads") for r in blas_info()]
    env = os.environ.get("OPENBLAS_NUM_THREADS")
    yield
    if before and before[0] is not None:
        set_blas_threads(before[0])
    if env is None:
        os.environ.pop("OPENBLAS_NUM_THREADS", None)
    else:
        os.environ["OPENBLAS_NUM_THREADS"] = env


def test_blas_single_thread():
    set_blas_threads(1)
    info = blas_info()
    assert info, "no OpenBLAS found in the process"
    assert all(r.get("threads") == 1 for r in info), info


@pytest.mark.parametrize("index", [0, 14, 28])
def test_fast_evaluation_matches_reference(index):
    """Values to round-off, Jacobians to the accuracy of the reference's central differences, at a
    committed stride moved off its optimum (seeded)."""
    rec = FAMILY["strides"][index]
    ref, fast = StepOptimizer(), FastStepOptimizer()
    ref.p = fast.p = rec["stride"]
    z = np.array(rec["c"]).ravel() + 1e-2 * np.random.default_rng(index).standard_normal(30)
    d = compare_evaluations(ref, fast, z)
    for k in ("obj", "crit", "gobj", "eq", "ineq"):
        assert d[k] < 1e-11, (k, d[k])
    for k in ("eq_jac", "ineq_jac"):
        assert d[k] < 1e-6, (k, d[k])
    # negative control: a Jacobian column of the end-of-step rows off by 1e-4 is seen
    e = dict(fast.evaluate(z))
    bad = e["eq_jac"].copy()
    bad[-1, 0] += 1e-4
    assert float(np.max(np.abs(bad - ref.evaluate(z)["eq_jac"]))) > 1e-6


def test_fast_evaluation_after_a_change_of_T():
    """The 1 m/s question changes T (and the basis) of an optimizer between solves: the fast evaluator
    follows (its end-of-step derivatives depend on dphi/dt = dphi/ds / T)."""
    from biped_controller.gaits.optimizer import basis, simpson_weights
    rec = FAMILY["strides"][14]
    ref, fast = StepOptimizer(), FastStepOptimizer()
    z = np.array(rec["c"]).ravel()
    fast.evaluate(z)  # evaluated once at the old T
    for o in (ref, fast):
        o.st = dataclasses.replace(o.st, T=0.4)
        o.phi, o.dphi, o.ddphi = basis(o.s, 0.4)
        o.w = simpson_weights(o.n, 0.4)
        o.p = 0.4
        o._cache_key = None
    d = compare_evaluations(ref, fast, z)
    assert d["eq"] < 1e-11 and d["obj"] < 1e-11 and d["eq_jac"] < 1e-6 and d["ineq_jac"] < 1e-6, d


def test_fast_impact_derivative_is_exact_in_velocity():
    """The end-of-step terms are linear in q'(T): the map A(q(T)) times q'(T) equals the values of the
    reference's impact, and A's columns equal a central difference of them."""
    fast = FastStepOptimizer()
    rec = FAMILY["strides"][10]
    c = np.array(rec["c"])
    qT, qdT = fast.phi[-1] @ c.T, fast.dphi[-1] @ c.T
    qd0, D, ineq, _ = fast._end_terms(qT, qdT)
    qd_ref, ineq_ref = fast._endpoint(qT, qdT)
    np.testing.assert_allclose(qd0, qd_ref, atol=1e-12)
    np.testing.assert_allclose(ineq, ineq_ref, atol=1e-12)
    for m in range(6):
        h = np.zeros(6)
        h[m] = 1e-6
        fd = (fast._endpoint(qT, qdT + h)[0] - fast._endpoint(qT, qdT - h)[0]) / 2e-6
        np.testing.assert_allclose(D[:, 6 + m], fd, atol=1e-7)


@pytest.fixture(scope="module")
def fast_builds():
    st = _reduced(strides=FOUR, smoothing_breakpoints=FOUR, smoothing_weights=[1.0e4])
    one, times = build_family(st, workers=1, evaluator="fast", progress=False, speed=False, max_sweeps=2)
    two, _ = build_family(st, workers=2, evaluator="fast", progress=False, speed=False, max_sweeps=2, memo=False)
    return st, one, two, times


def test_build_same_for_any_worker_count_and_with_or_without_the_memo(fast_builds):
    """The file of 1 worker process with the solve memo and of 2 without it, byte for byte; the memo was used
    (the first sweep's pass in a chain's direction repeats the chain's solves)."""
    _, one, two, times = fast_builds
    assert json.dumps(one, sort_keys=True) == json.dumps(two, sort_keys=True)
    assert times["sweep_memo_hits"] >= 2 and times["sweep_solves"] >= 1


def test_reduced_build_passes_its_checks(fast_builds):
    """Every stride and held-out stride feasible, the family within the fit tolerances at its held-out
    strides, the fitted family clean between the strides, and close to the committed family."""
    st, data, _, _ = fast_builds
    v = data["validation"]
    assert all(r["success"] for r in data["strides"]) and v["held_out_all_feasible"]
    assert v["held_out_fit_error_q_max"] <= st.fit_tolerance_q and v["held_out_fit_error_qdot_max"] <= st.fit_tolerance_qdot
    assert v["fitted_min_margin"] > 0 and v["fitted_min_clearance"] > 0
    assert max(r["periodicity_residual"] for r in data["strides"] + data["held_out"]) < 1e-6
    p_d = [r for r in data["strides"] if r["stride"] == st.p_d][0]
    p_d_committed = [r for r in FAMILY["strides"] if r["stride"] == st.p_d][0]
    # p_d is never smoothed: the same optimum as the committed one (a flat criterion, so loosely)
    assert abs(p_d["criterion"] - p_d_committed["criterion"]) < 1e-3 * p_d_committed["criterion"]


def test_reference_evaluator_gives_the_generators_numbers():
    """The build with the reference evaluator (2 workers, speculative sweeps, lazy diagnostics) gives the
    stride records of generation.solve_family + smooth_family (serial, this process) bit for bit."""
    st = _reduced(strides=FOUR, smoothing_breakpoints=FOUR, smoothing_weights=[1.0e4])
    set_blas_threads(1)
    data, _ = build_family(st, workers=2, evaluator="reference", progress=False, speed=False, max_sweeps=1)
    opt = StepOptimizer(settings=st)
    sols = solve_family(opt, list(st.strides), st.p_d, progress=False, max_sweeps=1)
    sols = smooth_family(opt, sols, st.p_d, st.smoothing_weights, progress=False)
    serial = [_solution_record(sols[p]) for p in sorted(sols)]
    assert json.dumps(data["strides"], sort_keys=True) == json.dumps(serial, sort_keys=True)


def test_build_refuses_the_committed_file():
    proc = subprocess.run([sys.executable, "-m", "biped_controller.gaits.build", "--out",
                           str(ROOT / "robots" / "biped7" / "gait_family.json")], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 2 and "refusing" in proc.stderr


def _held(stride, ok, eq, eqd, in_range):
    return {"stride": stride, "success": ok, "fit_error_q": eq, "fit_error_qdot": eqd, "in_range": in_range}


def test_acceptance_names_the_check_that_fails():
    """within_tolerance's reasons: a range collapsed to p_d names the held-out strides next to p_d with their
    fit errors (not 'could not be optimised' when every one was); an infeasible held-out stride is named."""
    from biped_controller.gaits.generation import within_tolerance
    st = load_gait_settings()
    clean = {"fitted_min_margin": 0.01, "fitted_min_clearance": 0.001, "fit_error_q_max": 0.0, "fit_error_qdot_max": 0.0}
    lo, hi = st.p_d - 0.0125, st.p_d + 0.0125
    collapsed = dict(clean, held_out=[_held(lo, True, 3e-2, 0.2, False), _held(hi, True, 4e-3, 0.05, False),
                                      _held(hi + 0.05, True, 1e-4, 1e-3, False)])
    ok, why = within_tolerance(collapsed, st)
    assert not ok and len(why) == 1
    assert why[0].startswith("the valid range collapsed to p_d"), why
    assert f"{lo:.4f} m optimised, fit error q 0.03 rad" in why[0] and f"{hi:.4f} m optimised" in why[0], why
    assert f"{hi + 0.05:.4f}" not in why[0] and "could not be optimised" not in why[0]
    inside = dict(clean, held_out=[_held(lo, False, 1e-4, 1e-3, True), _held(hi, True, 1e-4, 1e-3, True)],
                  held_out_all_feasible=False, held_out_fit_error_q_max=1e-4, held_out_fit_error_qdot_max=1e-3)
    ok, why = within_tolerance(inside, st)
    assert not ok and why == [f"a held-out stride could not be optimised: {lo:.4f} m"]
    good = dict(inside, held_out=[_held(lo, True, 1e-4, 1e-3, True)], held_out_all_feasible=True)
    assert within_tolerance(good, st) == (True, [])


def test_bad_gait_settings_name_their_own_file(tmp_path):
    """A gait.yaml that breaks a rule is refused naming that file (not the default robot's)."""
    import yaml
    from biped_controller.gaits.optimizer import GaitConfigError
    tree = yaml.safe_load((ROOT / "robots" / "biped7" / "gait.yaml").read_text())
    bp = tree["smoothing_breakpoints"]["value"]
    tree["smoothing_breakpoints"]["value"] = [bp[0], tree["preferred_stride"]["value"], bp[-1]]
    path = tmp_path / "gait.yaml"
    path.write_text(yaml.safe_dump(tree))
    with pytest.raises(GaitConfigError, match=rf"^{path}: smoothing_breakpoints must be at least 4"):
        load_gait_settings(path)


class _Interrupt(Exception):
    pass


def test_an_interrupted_build_resumes_to_the_same_file(fast_builds, tmp_path, monkeypatch):
    """A build stopped right after its first continuation sweep's checkpoint, run again with the same inputs,
    resumes from that checkpoint (it does not solve p_d and the chains again) and writes the file the
    uninterrupted build wrote, byte for byte; the checkpoint is gone at the end; other settings ignore it."""
    from biped_controller.gaits import build as B
    st, one, _, _ = fast_builds
    ck = B.checkpoint_path(tmp_path / "gait_family.json")
    save = B._Checkpoint.save

    def stop_after_sweep(self, phase, index, changed, sols):
        save(self, phase, index, changed, sols)
        if phase == "sweep":
            raise _Interrupt
    monkeypatch.setattr(B._Checkpoint, "save", stop_after_sweep)
    with pytest.raises(_Interrupt):
        build_family(st, workers=1, evaluator="fast", progress=False, speed=False, max_sweeps=2, checkpoint=ck)
    monkeypatch.setattr(B._Checkpoint, "save", save)
    assert ck.exists()
    from biped_model.robot import resolve_robot
    desc = resolve_robot(None).description()
    assert B._Checkpoint(ck, B.checkpoint_key(desc, st, "fast", None, 2)).load()["phase"] == "sweep"
    other = B.checkpoint_key(desc, dataclasses.replace(st, zmp_margin=st.zmp_margin * 1.01), "fast", None, 2)
    assert B._Checkpoint(ck, other).load() is None
    solved = []
    chain = B._chain
    monkeypatch.setattr(B, "_chain", lambda *a: solved.append(a) or chain(*a))
    resumed, _ = build_family(st, workers=1, evaluator="fast", progress=False, speed=False, max_sweeps=2,
                              checkpoint=ck)
    assert solved == []                          # p_d and the chains came from the checkpoint
    assert json.dumps(resumed, sort_keys=True) == json.dumps(one, sort_keys=True)
    assert not ck.exists()
