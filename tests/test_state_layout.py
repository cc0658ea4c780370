"""One state layout: the controller's and the simulator's per-period state are array-backed records
declared once (``robot.layout.Layout``), the objects keep their state in them and the compiled kernels take
the same arrays; the one home of the parameter advance and the observer's mode (``controller_kernels.begin``)
against closed forms; the mends (reset clears the decision, the torque within a period before any decision);
the typed floating-base model; kernel modules import without side effects."""
from __future__ import annotations

import inspect
import os
import subprocess
import sys
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from helpers import assert_close

from biped_model.description import LEFT, RIGHT, load_description
from biped_model.gait_family import GaitFamily
from biped_model.layout import Layout, LayoutError
from biped_sim.plant.config import load_sim_config
from biped_sim.plant.rigid import Simulator
from biped_sim.plant.rigid_layout import S_, SIM_STATE
from biped_controller.core.control.config import load_controller_config
from biped_controller.core.control.controller import AdaptiveController
from biped_controller.core.control.controller_compiled import load_controller_kernels
from biped_controller.core.control.controller_layout import (
    CONS, GAINS, M_, MEMORY, OBS_KEEP, OBS_NONE, OBS_RESIDUAL, R_, RES, WORK)

ROOT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------------------------ the declaration
def test_offsets_are_generated_from_the_declaration():
    lay = Layout("demo", [("a", 1), ("b", 3), ("c", 2)])
    assert tuple(lay.at) == (0, 1, 4) and lay.size == 6 and lay.at.b == 1
    assert lay.slice("b") == slice(1, 4) and lay.new().shape == (6,)
    for fields, word in (([("a", 1), ("a", 2)], "'a' declared twice"), ([("a", 0)], "'a' has size 0"),
                         ([("_x", 1)], "'_x'"), ([("b", True)], "'b' has size True"), ([], "no fields")):
        with pytest.raises(LayoutError, match=word):
            Layout("bad", fields)


@pytest.mark.parametrize("layout", [GAINS, CONS, MEMORY, RES, WORK, SIM_STATE], ids=lambda l: l.name)
def test_every_layout_tiles_its_array(layout):
    """Fields follow each other without gap or overlap and fill the array exactly."""
    covered = np.zeros(layout.size, dtype=int)
    for name in layout.at._fields:
        covered[layout.slice(name)] += 1
    assert np.all(covered == 1)


def test_numba_reads_the_offsets_as_the_python_side_does():
    """The compiled commit writes the memory fields where the Python properties read them."""
    ck = load_controller_kernels()
    mem, res, work, qd = MEMORY.new(), np.arange(RES.size, dtype=float) + 0.5, np.zeros((WORK.size, 6)), np.arange(6.0)
    work[WORK.at.w] = 7.0
    work[WORK.at.A:WORK.at.A + 6] = np.arange(36.0).reshape(6, 6)
    ck.commit(mem, res, work, qd, 2.5, RIGHT)
    assert mem[M_.p] == res[R_.p] and mem[M_.tau_dot] == res[R_.tau_dot]
    assert (mem[M_.p_ddot], mem[M_.tau_ddot], mem[M_.force]) == (res[R_.x], res[R_.x + 1], res[R_.force])
    assert (mem[M_.decided], mem[M_.t_last], mem[M_.stance], mem[M_.step]) == (1.0, 2.5, RIGHT, 1.0)
    assert np.array_equal(mem[MEMORY.slice("prev_qd")], qd) and np.all(mem[MEMORY.slice("prev_w")] == 7.0)
    assert np.array_equal(mem[MEMORY.slice("prev_A")], np.arange(36.0))


# ------------------------------------------------------------------------------------------ one advance, one mode
def _gains() -> np.ndarray:
    """A controller's GAINS (the family's p range [0.35, 0.65] m, which the advance holds p to)."""
    return AdaptiveController(load_controller_config(mode="both")).gains


def _memory(decided: bool, stance: int) -> np.ndarray:
    mem = MEMORY.new()
    mem[M_.p:M_.p + 6] = (0.41, 0.12, 0.21, 0.97, 2.5, -3.25)     # p inside the range over the periods below
    mem[M_.decided], mem[M_.t_last], mem[M_.stance], mem[M_.force] = float(decided), 1.0, stance, 42.0
    return mem


def test_begin_is_the_exact_advance_over_the_elapsed_nanoseconds():
    """p(h) = p + p' h + p'' h^2 / 2, p'(h) = p' + p'' h (tau likewise) with h from integer nanoseconds,
    against exact rational arithmetic; the memory is not changed."""
    ck = load_controller_kernels()
    t = 1.0 + 1234567e-9
    mem = _memory(True, LEFT)
    before = mem.copy()
    res = np.empty(RES.size)
    ck.begin(mem, _gains(), t, LEFT, res)
    assert np.array_equal(mem, before)
    h = Fraction(round(t * 1e9) - round(1.0 * 1e9), 10**9)
    p, pd, tau, taud, pdd, tdd = (Fraction(v) for v in before[M_.p:M_.p + 6])
    want = (p + pd * h + pdd * h * h / 2, pd + pdd * h, tau + taud * h + tdd * h * h / 2, taud + tdd * h)
    for k, (got, w) in enumerate(zip(res[R_.p:R_.p + 4], want)):
        assert abs(Fraction(got) - w) <= Fraction(1, 10**15) * max(1, abs(w)), k
    assert res[R_.obs_mode] == OBS_RESIDUAL and abs(res[R_.obs_dt] - 1234567e-9) < 1e-18
    # the same one function from Python (the torque within a period)
    assert ck.advance(*before[M_.p:M_.p + 6], float(h)) == tuple(res[R_.p:R_.p + 4])


def test_begin_restarts_the_phase_at_an_impact_and_keeps_the_estimate():
    ck = load_controller_kernels()
    res_same, res_new = np.empty(RES.size), np.empty(RES.size)
    g = _gains()
    ck.begin(_memory(True, LEFT), g, 1.001, LEFT, res_same)
    ck.begin(_memory(True, LEFT), g, 1.001, RIGHT, res_new)
    assert res_new[R_.tau] == 0.0 and res_same[R_.tau] != 0.0          # negative control: no impact, no restart
    assert res_new[R_.obs_mode] == OBS_KEEP and res_same[R_.obs_mode] == OBS_RESIDUAL
    assert np.array_equal(res_new[[R_.p, R_.p_dot, R_.tau_dot]], res_same[[R_.p, R_.p_dot, R_.tau_dot]])


def test_begin_before_any_decision_leaves_the_parameters():
    ck = load_controller_kernels()
    mem = _memory(False, LEFT)
    res = np.empty(RES.size)
    g = _gains()
    ck.begin(mem, g, 5.0, LEFT, res)
    assert np.array_equal(res[R_.p:R_.p + 4], mem[M_.p:M_.p + 4]) and res[R_.obs_mode] == OBS_NONE
    mem[M_.stance] = -1.0                     # reset without a stance: any stance, no restart
    ck.begin(mem, g, 5.0, RIGHT, res)
    assert res[R_.tau] == mem[M_.tau]


# ------------------------------------------------------------------------------------------ the objects' own arrays
def _pair():
    family = GaitFamily.load()
    sim = Simulator()
    ctrl = AdaptiveController(load_controller_config(mode="both"), family)
    q0, qd0 = family.initial_state()
    sim.reset(q0, qd0, LEFT)
    ctrl.reset(LEFT)
    return sim, ctrl


def test_controller_state_is_its_memory_array():
    sim, ctrl = _pair()
    obs = sim.observe()
    out = ctrl.compute(obs.t, obs.q, obs.qd, obs.stance)
    mem = ctrl.memory
    assert (ctrl.state.p, ctrl.state.tau_dot, ctrl.step_index, ctrl.stance) == (mem[M_.p], mem[M_.tau_dot], 1, LEFT)
    assert (out.status.p_ddot, out.status.tau_ddot) == (mem[M_.p_ddot], mem[M_.tau_ddot])
    ctrl.state.tau = 0.125
    assert mem[M_.tau] == 0.125


def test_reset_clears_the_decision_and_the_observer_memory():
    sim, ctrl = _pair()
    ctrl.state.p = ctrl.family.p_d + 0.01           # off p_d: the second task asks p'' != 0
    for _ in range(3):
        obs = sim.observe()
        sim.step(ctrl.compute(obs.t, obs.q, obs.qd, obs.stance).torque)
    mem = ctrl.memory
    assert mem[M_.decided] == 1.0 and mem[M_.step] == 3.0 and mem[M_.p_ddot] != 0.0   # negative control
    ctrl.reset(LEFT)
    assert mem[M_.decided] == 0.0 and mem[M_.step] == 0.0 and mem[M_.p_ddot] == 0.0 and mem[M_.tau_ddot] == 0.0
    assert not np.any(mem[MEMORY.slice("prev_qd").start:])
    assert (ctrl.state.p, ctrl.state.p_dot, ctrl.state.tau, ctrl.state.tau_dot) == (ctrl.family.p_d, 0.0, 0.0, 1.0)


@pytest.mark.parametrize("engine", ["fast", "reference"])
def test_torque_within_period_before_any_decision(engine):
    """Eqs. (11), (16), (15) at the initial parameters (p = p_d, p' = 0, tau = 0, tau' = 1, p'' = tau'' = 0),
    written out here from the family's partial derivatives and the reference model."""
    family = GaitFamily.load()
    ctrl = AdaptiveController(load_controller_config(mode="both", engine=engine), family)
    ctrl.reset(LEFT)
    rng = np.random.default_rng(23)
    q0, qd0 = family.initial_state()
    q, qd = q0 + rng.normal(scale=0.01, size=6), qd0 + rng.normal(scale=0.1, size=6)
    s = 0.0004
    g = family.evaluate(family.p_d, s)            # tau(s) = 0 + 1 s, p(s) = p_d
    q_d, qd_d, qdd_d = g.q, g.dq_dtau, g.d2q_dtau2
    c = ctrl.cfg
    w = qdd_d + c.Kv * (qd_d - qd) + c.Kp * (q_d - q)
    dyn = ctrl.model.dynamics(q, qd)
    assert_close(ctrl.torque_within_period(s, q, qd, LEFT), dyn.A @ w + dyn.H, 1e-9, "torque within the period")


def test_simulator_state_is_its_array_and_records_do_not_alias_it():
    sim, ctrl = _pair()
    st = sim.sim_state
    assert np.shares_memory(sim.x, st) and np.shares_memory(sim.anchor, st)      # views of the one array
    assert sim.t == st[S_.t] and sim.stance == int(st[S_.stance]) == LEFT
    a = np.arange(9.0)
    sim.v = a
    a[0] = -1.0
    assert sim.v[0] == 0.0                                                       # assignment copies
    sim.reset(*ctrl.family.initial_state(), LEFT)
    recs = []
    for _ in range(3):
        obs = sim.observe()
        recs.append(sim.step(ctrl.compute(obs.t, obs.q, obs.qd, obs.stance).torque))
    for r in recs:
        for name in ("x", "v", "q", "qd", "base", "base_dot"):
            assert not np.shares_memory(getattr(r, name), st), name
    assert not np.array_equal(recs[0].x, recs[2].x) and np.array_equal(recs[2].t_end, sim.t)


def test_the_compiled_loop_runs_on_the_objects_own_arrays(monkeypatch):
    from biped_controller.closed_loop.segment import Segment
    sim, ctrl = _pair()
    seg = Segment(sim, ctrl)
    seen = {}
    orig = seg.lk.run_segment

    class Spy:
        END_NAMES = seg.lk.END_NAMES
        REC = seg.lk.REC

        @staticmethod
        def run_segment(*args):
            seen["mem"], seen["sst"], seen["gains"], seen["lim"] = args[7], args[10], args[5], args[11]
            return orig(*args)
    seg.lk = Spy
    mem, sst = ctrl.memory, sim.sim_state
    recs, stats = seg.run(0.05)
    assert seen["mem"] is mem and seen["sst"] is sst and seen["gains"] is ctrl.gains and seen["lim"] is sim.limits
    assert ctrl.memory is mem and sim.sim_state is sst                           # nothing packed, nothing replaced
    assert len(recs) > 10 and ctrl.step_index == sim.step_index == len(recs) and sim.t >= 0.05


# ------------------------------------------------------------------------------------------ the floating-base model
def test_both_floating_models_satisfy_one_protocol():
    from biped_model.fast_engine import FastFloatingModel
    from biped_model.floating import FloatingModel
    from biped_model.floating_base import CompiledFloatingModel, FloatingBaseModel, make_floating_model
    desc = load_description()
    ref, fast = make_floating_model(desc, "reference"), make_floating_model(desc, "fast")
    assert type(ref) is FloatingModel and type(fast) is FastFloatingModel
    assert isinstance(ref, FloatingBaseModel) and isinstance(fast, CompiledFloatingModel)
    assert not isinstance(ref, CompiledFloatingModel)                            # negative control
    for proto, classes in ((FloatingBaseModel, (FloatingModel, FastFloatingModel)), (CompiledFloatingModel, (FastFloatingModel,))):
        for name, member in vars(proto).items():
            if name.startswith("_") or not callable(getattr(proto, name, None)):
                continue
            want = list(inspect.signature(getattr(proto, name)).parameters)
            for cls in classes:
                got = list(inspect.signature(getattr(cls, name)).parameters)
                assert got == want, (cls.__name__, name, got, want)

    Partial = type("Partial", (), {"desc": desc, "mass": 1.0, "joint_names": ()})   # every member but `impact`
    for name in dir(FloatingBaseModel):
        if not name.startswith("_") and name != "impact" and callable(getattr(FloatingBaseModel, name)):
            setattr(Partial, name, lambda self, *a: None)
    assert not isinstance(Partial(), FloatingBaseModel)
    with pytest.raises(ValueError, match="'warp'"):
        make_floating_model(desc, "warp")
    assert Simulator(config=load_sim_config(engine="reference"))._pk is None


# ------------------------------------------------------------------------------------------ imports without side effects
def _python(code: str, env: dict) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600, cwd=ROOT)


def test_kernel_modules_import_without_side_effects(tmp_path):
    """Importing the modules around the kernels compiles, prints, writes and sets nothing; a kernel module
    imported directly (not through numba_cache.load) refuses instead of caching in a stray place."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    code = ("import os, sys, numba\n"
            "import biped_model.fast_engine, biped_sim.plant.rigid, biped_controller.core.control.controller\n"
            "import biped_controller.core.qp.solver, biped_controller.closed_loop.segment, biped_controller.closed_loop.runner\n"
            "import biped_controller.core.sensing.model_error\n"
            "kern = [m for m in ('biped_model.planar_kernels', 'biped_controller.core.qp.exact_kernels',\n"
            "        'biped_controller.core.control.controller_kernels', 'biped_controller.core.control.wbc_kernels',\n"
            "        'biped_controller.closed_loop.loop_kernels', 'biped_controller.core.sensing.model_error_kernels')\n"
            "        if m in sys.modules]\n"
            "print(kern, 'NUMBA_CACHE_DIR' in os.environ, repr(numba.config.CACHE_DIR))\n")
    out = _python(code, env)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[] False ''" and out.stderr == ""
    for mod in ("biped_model.planar_kernels", "biped_controller.core.sensing.model_error_kernels"):
        direct = _python(f"import {mod}", env)
        assert direct.returncode != 0 and "CacheNotConfigured" in direct.stderr and "numba_cache.load" in direct.stderr
    # through load: the repository's cache, nothing printed when it is warm (setup compiled it)
    loaded = _python("from biped_model.fast_engine import planar_kernels; import numba; planar_kernels(); "
                     "print(numba.config.CACHE_DIR)", env)
    assert loaded.returncode == 0, loaded.stderr
    assert Path(loaded.stdout.strip()) == ROOT / "build" / "numba-cache"
