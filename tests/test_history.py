"""A trial's record is a function of the trial alone: the same in a new process, on new objects, and on a
worker's plant, controller and QP solvers reused after other trials (the sweeps' ``runner.LoopPool``).

The leak this guards against was PIQP's ``update``: it unscales the data a solver object holds with the
previous instance's Ruiz scaling and scales it again with the new one, so the data not passed again
drift by rounding from solve to solve, and a controller reused across trials answered a trial's QPs
differently after other trials (``solver.AdaptationQP`` now sets every solve up from its instance).
Each test has a negative control that puts the held update back (:func:`leaky_updates`): the same
comparison then fails, so the tests can fail. All randomness is seeded.
"""
from __future__ import annotations

import dataclasses
import random

import numpy as np
import pytest

from biped_sim.plant.push import Push

from biped_controller.core.qp import solver as qp
from biped_controller.core.qp.solver import AdaptationQP
from biped_controller.closed_loop import runner
from biped_controller.studies.capmap import task
from biped_controller.studies.capmap.spec import Cell, SimSpec
from biped_controller.studies.trial import trials
from biped_controller.studies.trial import context as tcontext
from biped_controller.studies.trial import settings as ts

from test_qp import rand_feasible, rand_infeasible, rand_W

MUJOCO = ts.parse_overrides(["plant=mujoco"])


def leaky_updates(monkeypatch) -> None:
    """The negative control: every held PIQP object set up on its first solve and then only updated (the
    behaviour before the fix: the previous instance's scaling left in the object's data)."""
    monkeypatch.setattr(qp.AdaptationQP, "_run", qp.held_update_run)


def same_answer(a, b) -> bool:
    """Every field of two ``QPResult`` bit for bit (arrays too; a missing z on both counts as equal)."""
    for f in dataclasses.fields(a):
        u, v = getattr(a, f.name), getattr(b, f.name)
        if isinstance(u, np.ndarray) or isinstance(v, np.ndarray):
            if u is None or v is None or not np.array_equal(u, v):
                return False
        elif u != v:
            return False
    return True


def instances(n: int, count: int = 200, seed: int = 11):
    """Seeded QPs with n variables, 17 rows scaled over two decades: x* mostly outside, every tenth
    infeasible (the least-violation fallback), weights changed every 25 instances."""
    rng = np.random.default_rng(seed + n)
    W = rand_W(rng, n)
    out = []
    for i in range(count):
        if i % 25 == 0:
            W = rand_W(rng, n)
        if i % 10 == 9 and n == 2:
            G, h, x_star, _ = rand_infeasible(rng, n)
        else:
            G, h, x_star, _, _ = rand_feasible(rng, n, spread=5.0 if i % 3 else 0.1)
        out.append((G, h, x_star, W))
    return out


def held_vs_fresh(n: int, polish: bool) -> tuple[int, int]:
    """(answers of one held solver that differ from a new solver's on the same instance, PIQP solves)."""
    kw = dict(solver="piqp", fallback="piqp", polish=polish)
    held = AdaptationQP(n, 17, np.ones(n), **kw)
    differ = 0
    for G, h, x_star, W in instances(n):
        held.set_weights(W)
        fresh = AdaptationQP(n, 17, W, **kw)
        if not same_answer(held.solve(G, h, x_star), fresh.solve(G, h, x_star)):
            differ += 1
    return differ, held.calls


@pytest.mark.parametrize("n,polish", [(2, True), (2, False), (3, False), (6, True)])
def test_a_qp_answer_is_a_function_of_its_instance_alone(n, polish):
    """One held solver answering a sequence of instances gives, on each, the answer of a new solver on that
    instance alone, bit for bit: the screening and tight PIQP objects (``polish`` True: the screening solve
    then the tight one when the polish rejects it; False: the preconditioned tight solver on every call)
    and the least-violation slack QP (``fallback="piqp"``, the infeasible instances)."""
    differ, calls = held_vs_fresh(n, polish)
    assert calls > 150            # PIQP ran on most instances (not the early-out)
    assert differ == 0


def test_held_updates_make_the_answers_depend_on_the_earlier_instances(monkeypatch):
    """Negative control: with PIQP's update on the held objects the answers differ from a new solver's."""
    leaky_updates(monkeypatch)
    differ, _ = held_vs_fresh(2, False)
    assert differ > 0


def test_the_slack_qp_answer_is_a_function_of_its_instance_alone():
    rng = np.random.default_rng(5)
    held = qp.SlackQP(2, 17)
    for _ in range(40):
        G, h, x_star, W = rand_infeasible(rng, 2)
        a = held.solve(G, h, x_star, W, 1e-6)
        b = qp.SlackQP(2, 17).solve(G, h, x_star, W, 1e-6)
        assert np.array_equal(a[0], b[0]) and a[1:] == b[1:]


# ------------------------------------------------------------------------------------------ trials
# the MuJoCo 25 ms slice's trial whose min_p came out an ulp apart in a map run and alone (mode both,
# backward, phase 0.4, 1100 N), and a trial run before it on the same worker objects
TARGET = SimSpec(Cell("both", "backward", 0.4, 0.025), 1100.0)
BEFORE = SimSpec(Cell("both", "forward", 0.2, 0.025), 1300.0)


def mujoco_records() -> tuple[dict, dict]:
    """(the target's map record on new objects, the same after BEFORE on one reused pool)."""
    alone = task.simulate(TARGET, MUJOCO, pool=runner.LoopPool())
    pool = runner.LoopPool()
    task.simulate(BEFORE, MUJOCO, pool=pool)
    return alone, task.simulate(TARGET, MUJOCO, pool=pool)


def test_a_mujoco_map_record_is_the_same_alone_and_after_another_trial():
    alone, after = mujoco_records()
    assert alone["cause"] == "foot_rotated" and alone["min_p"] is not None
    assert after == alone


def test_a_mujoco_map_record_depends_on_the_trial_before_with_held_updates(monkeypatch):
    """Negative control: the held update put back, the record after the other trial is not the one alone
    (measured: min_p and max |p - p_d| an ulp apart)."""
    leaky_updates(monkeypatch)
    alone, after = mujoco_records()
    assert after != alone
    assert {k for k in alone if alone[k] != after[k]} <= {"min_p", "max_p", "max_abs_p_minus_pd", "min_tau_dot",
                                                          "max_tau_dot", "fall_time", "reason"}


RIGID_TRIALS = [(m, ph, du, f) for m in ("both", "tau", "p", "hybrid", "all", "wbc", "lambda", "none")
                for ph, du, f in ((0.25, 0.025, 700.0), (0.75, 0.025, -900.0), (0.5, 0.1, 300.0))]


def test_rigid_trials_are_the_same_alone_and_after_other_trials():
    """The rigid plant's trials of every mode (survivals, falls, both directions): each on new objects,
    then all of them twice through one pool in a seeded shuffled order, record for record. (No rigid trial
    was found that the held update changes, so this test has no negative control of its own; the QP's and
    MuJoCo's have.)"""
    T = tcontext.context().family.T
    pushes = {s: Push(s[1] * T, s[2], s[3]) for s in RIGID_TRIALS}
    alone = {s: trials.survives(pushes[s], s[0], ts.DEFAULT_SETTINGS, pool=runner.LoopPool()) for s in RIGID_TRIALS}
    assert {r["survived"] for r in alone.values()} == {True, False}
    pool = runner.LoopPool()
    order = RIGID_TRIALS * 2
    random.Random(3).shuffle(order)
    for s in order:
        assert trials.survives(pushes[s], s[0], ts.DEFAULT_SETTINGS, pool=pool) == alone[s], s
