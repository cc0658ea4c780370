"""The trajectory parameters stay in their valid range (p in the family's [p_min, p_max], tau' >= tau_dot_min)
in every mode, including when the p/tau QP has no feasible answer and mode hybrid's whole-body stage takes the
period (core/control/controller.py ``_hold_ranges``); the runs' and the capability map's records of the
parameters' excursion (studies/trial/trials.py ``parameter_excursion``)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from helpers import assert_same_run

from biped_sim.plant.push import Push
from biped_controller.core.control.config import load_controller_config
from biped_controller.core.control.controller import AdaptiveController, computed_torque, joint_law
from biped_controller.core.control.controller_compiled import load_controller_kernels
from biped_model.gait_family import eq11
from biped_controller.core.control.controller_layout import M_, MEMORY, R_, RES
from biped_controller.closed_loop import runner
from biped_controller.core.qp.problem import INFEASIBLE_FALLBACK
from biped_controller.core.control.wbc import NOT_RUN
from biped_controller.studies.capmap.spec import Cell, SimSpec, onset_time
from biped_controller.studies.capmap.task import simulate
from biped_controller.studies.trial import runs, trials
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.settings import run_settings
from biped_controller.core.control.config import MODES

HELD = "held to the parameters' ranges"


def _in_range(statuses, fam, tau_dot_min, tau_dot_max=math.inf):
    p = np.array([s.p for s in statuses])
    td = np.array([s.tau_dot for s in statuses])
    tol = trials.RANGE_TOL
    return p, td, bool(np.all(p >= fam.p_min - tol) and np.all(p <= fam.p_max + tol)
                       and np.all(td >= tau_dot_min - tol) and np.all(td <= tau_dot_max + tol))


def test_hold_puts_the_next_parameters_on_the_range_bounds():
    """A least-violation answer far outside the range rows (p'' = +-1e6 m/s^2, tau'' = -1e6 1/s): held so that
    p after one period and after a second one at the new p' (no acceleration) are in range, one of them on the
    bound, and tau' lands on tau_dot_min; an answer inside the rows is not touched; a mode that does not
    adapt p keeps p'' (its x*); from a state whose second period cannot be held (p' dt beyond the range)
    p after one period is still held."""
    ctrl = AdaptiveController(load_controller_config(mode="hybrid"))
    fam, dt, tdm = ctrl.family, ctrl.cfg.period, ctrl.cfg.tau_dot_min
    res = np.zeros(RES.size)
    res[R_.p], res[R_.p_dot], res[R_.tau_dot] = 0.60, 0.8, 0.4
    for p_dd, bound in ((1e6, fam.p_max), (-1e6, fam.p_min)):
        x = np.array([p_dd, -1e6])
        msg = ctrl._hold_ranges(x, res, None)
        assert HELD in msg and "p''" in msg and "tau''" in msg
        p1, pd1, _, td1 = ctrl.ck.advance(0.60, 0.8, 0.0, 0.4, x[0], x[1], dt)
        p2 = p1 + pd1 * dt
        tol = 1e-12
        assert fam.p_min - tol <= p1 <= fam.p_max + tol and fam.p_min - tol <= p2 <= fam.p_max + tol
        assert min(abs(p1 - bound), abs(p2 - bound)) < tol
        assert td1 == pytest.approx(tdm, abs=1e-12)
    fast = res.copy()
    fast[R_.p_dot] = -1000.0            # p' dt = -1 m: no p'' keeps the second period in range
    x = np.array([-1e6, 0.0])
    ctrl._hold_ranges(x, fast, None)
    assert ctrl.ck.advance(0.60, -1000.0, 0.0, 0.4, x[0], 0.0, dt)[0] == pytest.approx(fam.p_min, abs=1e-12)
    x = np.array([-50.0, 2.0])
    assert ctrl._hold_ranges(x, res, None) == "" and list(x) == [-50.0, 2.0]
    tau_only = AdaptiveController(load_controller_config(mode="tau"))
    x = np.array([1e6, -1e6])
    tau_only._hold_ranges(x, res, None)
    assert x[0] == 1e6 and x[1] == pytest.approx((tdm - 0.4) / dt)


@pytest.fixture(scope="module")
def mujoco_700():
    """Mode hybrid, 700 N for 25 ms at phase 0.55 of the first step, on the MuJoCo plant (deterministic), and
    the settings. With 0.5 ms MuJoCo steps: there the p/tau QP turns infeasible and the hold acts (with the
    default 0.125 ms step this push leaves the QP feasible, so the checks below would check little)."""
    settings = run_settings(None, ["plant=mujoco", "mujoco_timestep=0.0005"])
    fam = context().family
    push = Push(onset_time(0.55, fam.T), 0.025, 700.0, None)
    return runs.push_run(push, "hybrid", steps_after=3, settings=settings), settings


def test_hybrid_700n_on_mujoco_stays_in_range_and_ends_physically(mujoco_700):
    """The p/tau QP is infeasible and the whole-body stage takes periods, the hold acts, yet every period's p
    and tau' are finite and in range; the run walks or ends in one of the plant's physical falls; the run's
    recorded excursion equals its periods' extremes."""
    r, settings = mujoco_700
    cc = settings.ctrl_config("hybrid")
    fam, tdm = context().family, cc.tau_dot_min
    p, td, ok = _in_range(r.statuses, fam, tdm, cc.tau_dot_max)
    assert np.all(np.isfinite(p)) and np.all(np.isfinite(td))
    assert ok, (p.min(), p.max(), td.min())
    assert sum(s.qp_status == INFEASIBLE_FALLBACK for s in r.statuses) >= 5
    assert sum(s.wbc_status != NOT_RUN for s in r.statuses) >= 5
    assert any(HELD in s.qp_message for s in r.statuses), "the hold never acted: the test checks little"
    assert not r.fallen or r.fall_cause in ("body_contact", "hip_low", "foot_rotated"), r.fall_cause
    assert r.param_range == (p.min(), p.max(), td.min(), td.max())


def test_python_steps_equal_the_compiled_period_where_the_hold_acts(mujoco_700):
    """The states of that run fed to a controller on its compiled period and to one on its Python steps (with
    the Python whole-body stage), the Python one restored to the compiled one's memory before every period, so
    each period compares one decision from one state (no round-off carried from period to period): the same QP
    and stage statuses and the same periods held, and the decisions (p'', tau'') and parameters equal to the
    round-off of the two stages' arithmetic (they reach the same optimum by different operations,
    test_wbc_kernels)."""
    run = mujoco_700[0]
    recs = run.records
    comp = AdaptiveController(load_controller_config(mode="hybrid"))
    py = AdaptiveController(load_controller_config(mode="hybrid"))
    py._kernel = None
    comp.reset(recs[0].stance)
    py.reset(recs[0].stance)
    held = 0
    for k, x in enumerate(recs):
        py.restore(comp.snapshot())
        sa = comp.compute(x.t, x.q, x.qd, x.stance).status
        sb = py.compute(x.t, x.q, x.qd, x.stance).status
        assert (sa.qp_status, sa.wbc_status, HELD in sa.qp_message) == \
            (sb.qp_status, sb.wbc_status, HELD in sb.qp_message), (k, sa.t)
        for f, tol in (("p", 1e-9), ("tau_dot", 1e-9), ("p_ddot", 1e-5), ("tau_ddot", 1e-5)):
            assert getattr(sa, f) == pytest.approx(getattr(sb, f), rel=tol, abs=tol), (k, sa.t, f)
        held += HELD in sa.qp_message
    assert held >= 1, "no period where the hold acted: the comparison checks little"


def test_hold_keeps_tau_dot_below_its_upper_end():
    """A least-violation answer with tau'' = +1e6 1/s: held so that tau' after one period lands on tau_dot_max
    (the end the QP has no row for); an answer below it is not touched."""
    ctrl = AdaptiveController(load_controller_config(mode="both"))
    dt, tdx = ctrl.cfg.period, ctrl.cfg.tau_dot_max
    res = np.zeros(RES.size)
    res[R_.p], res[R_.p_dot], res[R_.tau_dot] = 0.463, 0.0, 3.0
    x = np.array([0.0, 1e6])
    assert "tau''" in ctrl._hold_ranges(x, res, None)
    assert ctrl.ck.advance(0.463, 0.0, 0.0, 3.0, x[0], x[1], dt)[3] == pytest.approx(tdx, abs=1e-12)
    x = np.array([0.0, (tdx - 3.0) / dt * 0.5])
    assert ctrl._hold_ranges(x, res, None) == "" and x[1] == (tdx - 3.0) / dt * 0.5


@pytest.mark.parametrize("tau_dot_max", [None, 1e9])
def test_a_mujoco_fall_keeps_tau_dot_in_range(tau_dot_max):
    """Mode both, 750 N for 25 ms at phase 0.6 on MuJoCo: the robot falls and the p/tau QP is infeasible for
    many periods; tau' stays within [tau_dot_min, tau_dot_max]. Negative control (tau_dot_max = 1e9, i.e. no
    upper end): tau' runs far past the configured tau_dot_max in the same fall."""
    sets = ["plant=mujoco"] + ([f"tau_dot_max={tau_dot_max}"] if tau_dot_max else [])
    settings = run_settings(None, sets)
    fam = context().family
    r = runs.push_run(Push(onset_time(0.6, fam.T), 0.025, 750.0, None), "both", steps_after=3, settings=settings)
    assert r.fallen and r.fall_cause == "foot_rotated", (r.fallen, r.fall_cause)
    assert sum(s.qp_status == INFEASIBLE_FALLBACK for s in r.statuses) >= 5
    configured = load_controller_config()
    p, td, ok = _in_range(r.statuses, fam, configured.tau_dot_min, configured.tau_dot_max)
    if tau_dot_max is None:
        assert ok, (p.min(), p.max(), td.min(), td.max())
        assert td.max() > 10.0            # the QP does use tau' (the hold is not all that acts)
    else:
        assert td.max() > 10 * configured.tau_dot_max, td.max()


def test_every_mode_of_a_small_map_slice_stays_in_range():
    """A small capability-map slice (phase 0.55, 25 ms, forward, 300 and 900 N) in every mode: each record
    carries the trial's excursion, and no trial leaves the range."""
    ctrl_cfg = load_controller_config()
    fam = context().family
    for mode in MODES:
        for force in (300.0, 900.0):
            rec = simulate(SimSpec(Cell(mode, "forward", 0.55, 0.025), force))
            for k in ("max_abs_p_minus_pd", "min_p", "max_p", "min_tau_dot", "max_tau_dot"):
                assert math.isfinite(rec[k]), (mode, force, k)
            assert rec["max_abs_p_minus_pd"] == max(rec["max_p"] - fam.p_d, fam.p_d - rec["min_p"])
            why = trials.out_of_range(rec, fam.p_min, fam.p_max, ctrl_cfg.tau_dot_min, ctrl_cfg.tau_dot_max)
            assert why == "", (mode, force, why)


def test_out_of_range_names_what_leaves():
    """Negative control of the range check: each bound broken alone is named; NaN and a record from before the
    fields existed are not passed."""
    ok = {"min_p": 0.40, "max_p": 0.60, "min_tau_dot": 0.5, "max_tau_dot": 3.0}
    R = (0.35, 0.65, 0.05, 46.3)
    assert trials.out_of_range(ok, *R) == ""
    assert "p_min" in trials.out_of_range({**ok, "min_p": 0.30}, *R)
    assert "p_max" in trials.out_of_range({**ok, "max_p": 1e13}, *R)
    assert "tau_dot_min" in trials.out_of_range({**ok, "min_tau_dot": -3e13}, *R)
    assert trials.out_of_range({**ok, "min_tau_dot": 0.05 - 1e-16}, *R) == ""   # on the bound
    assert "tau_dot_min" in trials.out_of_range({**ok, "min_tau_dot": 0.05 - 1e-9}, *R)
    assert "tau_dot_max" in trials.out_of_range({**ok, "max_tau_dot": 1.6e4}, *R)
    assert trials.out_of_range({**ok, "max_tau_dot": 46.3}, *R) == ""            # on the bound
    assert trials.out_of_range({**ok, "max_p": math.nan}, *R) != ""
    assert trials.out_of_range({**ok, "max_tau_dot": math.nan}, *R) != ""
    assert trials.out_of_range({"mode": "both"}, *R) == "parameter excursion not recorded"
    assert trials.out_of_range({**ok, "min_p": None}, *R) == "parameter excursion not recorded"


# ------------------------------------------------------------------------ p's range inside a period cut short
def _free_p(prev, cur) -> tuple[float, float]:
    """(p, p') of status ``cur`` by the free integration from ``prev`` (no limit): the advance before the
    integration had its limit, over the integer nanoseconds between the two decisions (``period_start``)."""
    h = (round(cur.t * 1e9) - round(prev.t * 1e9)) * 1e-9
    p, pd, _, _ = load_controller_kernels().advance(prev.p, prev.p_dot, 0.0, 0.0, prev.p_ddot, 0.0, h)
    return p, pd


def test_limit_of_the_advance_in_closed_form():
    """``controller_kernels.limited`` and the period's start (``begin``) on constructed states against their
    closed forms: from p = 0.64996 m, p' = 1.92 m/s, p'' = -3757 m/s^2 a period cut 0.375 ms in by an impact
    ends at p = 0.64996 + 1.92 h - 3757 h^2 / 2 = 0.650416 m, past p_max (the free advance, the negative
    control), and is held to (p_max, 0): p'(h) = 0.511 m/s points out of the range. Past the bound with an
    inward p' (1 m/s, -1000 m/s^2 over 1.5 ms: p' = -0.5 m/s) p is held and p' kept; the lower bound alike;
    a state on the bound keeps an inward p' and loses an outward one; inside the range the advance is the free
    one bit for bit; lambda likewise at +-lambda_max in mode all."""
    ck = load_controller_kernels()
    gains = AdaptiveController(load_controller_config(mode="both")).gains
    fam = context().family
    lo, hi = fam.p_min, fam.p_max

    def start(p, pd, pdd, h, stance=1, g=gains, lam=(0.0, 0.0, 0.0)):
        mem = MEMORY.new()
        mem[M_.p:M_.p + 6] = (p, pd, 0.37, 1.0, pdd, 0.0)
        mem[M_.lam], mem[M_.lam_dot], mem[M_.lam_ddot] = lam
        mem[M_.decided], mem[M_.t_last], mem[M_.stance] = 1.0, 0.373, 0
        res = np.full(RES.size, np.nan)
        ck.begin(mem, g, 0.373 + h, stance, res)
        return res

    h = 0.375e-3
    free = ck.advance(0.64996, 1.92, 0.37, 1.0, -3757.0, 0.0, h)
    assert free[0] == pytest.approx(0.64996 + 1.92 * h - 0.5 * 3757.0 * h * h, abs=1e-15)
    assert free[0] - hi > 4e-4 and free[1] == pytest.approx(1.92 - 3757.0 * h, abs=1e-12) and free[1] > 0
    res = start(0.64996, 1.92, -3757.0, h)
    assert (res[R_.p], res[R_.p_dot]) == (hi, 0.0)
    assert (res[R_.tau], res[R_.tau_dot]) == (0.0, 1.0)          # an impact: tau restarts, tau' unchanged
    res = start(0.64999, 1.0, -1000.0, 1.5e-3, stance=0)
    assert (res[R_.p], res[R_.p_dot]) == (hi, ck.advance(0.64999, 1.0, 0.0, 0.0, -1000.0, 0.0, 1.5e-3)[1])
    assert res[R_.p_dot] == pytest.approx(-0.5, abs=1e-12)
    assert (start(0.35001, -1.0, 1000.0, 1.5e-3)[R_.p_dot], start(0.35001, -1.0, 1000.0, 1.5e-3)[R_.p]) == \
        (pytest.approx(0.5, abs=1e-12), lo)
    assert (start(0.35001, -1.0, 1000.0, h)[R_.p], start(0.35001, -1.0, 1000.0, h)[R_.p_dot]) == (lo, 0.0)
    assert ck.limit(hi, 0.3, lo, hi) == (hi, 0.0) and ck.limit(hi, -0.3, lo, hi) == (hi, -0.3)
    assert ck.limit(lo, -0.3, lo, hi) == (lo, 0.0) and ck.limit(lo, 0.3, lo, hi) == (lo, 0.3)
    inside = start(0.5, 1.92, -3757.0, h, stance=0)
    assert (inside[R_.p], inside[R_.p_dot]) == ck.advance(0.5, 1.92, 0.37, 1.0, -3757.0, 0.0, h)[:2]
    # lambda (mode all): held at +-lambda_max like p; in mode both (no torso) the memory's lambda is not held
    g_all = AdaptiveController(load_controller_config(mode="all")).gains
    lm = load_controller_config(mode="all").lambda_max
    lam_free = 0.2999 + 1.0 * h - 0.5 * 1000.0 * h * h
    assert lam_free > lm
    res = start(0.5, 0.0, 0.0, h, g=g_all, lam=(0.2999, 1.0, -1000.0))
    assert (res[R_.lam], res[R_.lam + 1]) == (lm, 0.0)
    res = start(0.5, 0.0, 0.0, h, g=g_all, lam=(-0.2999, -1.0, 1000.0))
    assert (res[R_.lam], res[R_.lam + 1]) == (-lm, 0.0)
    res = start(0.5, 0.0, 0.0, h, lam=(0.2999, 1.0, -1000.0))
    assert res[R_.lam] == pytest.approx(lam_free, abs=1e-15)


def test_the_reference_within_a_period_uses_the_held_advance():
    """``torque_within_period`` at s = 0.375 ms from the cut-short state above is eqs. (11), (16), (15) at the
    held parameters (p_max, p' = 0, tau and tau' advanced freely), bit for bit; at the free ones (p past
    p_max) the same law gives another torque (negative control)."""
    ctrl = AdaptiveController(load_controller_config(mode="both"))
    ck, fam, cfg, h = ctrl.ck, ctrl.family, ctrl.cfg, 0.375e-3
    q, qd = np.array([0.1, -0.2, 0.3, 0.2, -0.4, 0.1]), np.array([0.5, -0.3, 0.2, 0.1, -0.2, 0.4])
    ctrl.memory[M_.p:M_.p + 6] = (0.64996, 1.92, 0.1, 1.0, -3757.0, 2.0)
    ctrl.memory[M_.decided] = 1.0
    cut = ctrl.torque_within_period(h, q, qd, 0)
    p_free, pd_free, tau_h, taud_h = ck.advance(0.64996, 1.92, 0.1, 1.0, -3757.0, 2.0, h)
    dyn, _ = ctrl._model_terms(q, qd)

    def law(p, pd):
        qr, qdr, qddr = eq11(fam.evaluate(p, tau_h), pd, taud_h, -3757.0, 2.0)
        return computed_torque(dyn.A, dyn.H, joint_law(qr, qdr, qddr, q, qd, cfg.Kp, cfg.Kv))

    assert np.array_equal(cut, law(fam.p_max, 0.0))
    assert not np.allclose(cut, law(p_free, pd_free), rtol=1e-9, atol=1e-9)


@pytest.fixture(scope="module")
def mujoco_cut_short():
    """Mode both, 750 N forward for 25 ms at phase 0.65 of the first step (default profile), on the MuJoCo plant
    (deterministic): a period held at p's upper bound by the QP's hold is cut 0.375 ms in by a touchdown."""
    settings = run_settings(None, ["plant=mujoco"])
    push = Push(onset_time(0.65, context().family.T), 0.025, 750.0, None)
    return runs.push_run(push, "both", steps_after=3, settings=settings), settings, push


def test_a_period_cut_short_by_a_touchdown_keeps_p_in_range(mujoco_cut_short):
    """Every period's p of that trial is within [p_min, p_max] (exactly, no tolerance), and the trial's recorded
    excursion says so. Negative control, the former code path: until the integration's limit first acts,
    each period's (p, p') is the free advance of the previous period's (bit for bit, so the run is the former
    one up to there); where it acts, a period cut short by the touchdown (0.375 ms), the free advance puts p
    more than 0.3 mm past p_max -- what the former code recorded."""
    r, _, _ = mujoco_cut_short
    fam, st = context().family, r.statuses
    p = np.array([s.p for s in st])
    assert np.all(p >= fam.p_min) and np.all(p <= fam.p_max), (p.min(), p.max())
    assert r.param_range[:2] == (p.min(), p.max()) and p.max() == fam.p_max
    k = next(j for j in range(1, len(st)) if (st[j].p, st[j].p_dot) != _free_p(st[j - 1], st[j]))
    free_p, free_pd = _free_p(st[k - 1], st[k])
    assert free_p - fam.p_max > 3e-4 and free_pd > 0.0, (free_p, free_pd)
    assert (st[k].p, st[k].p_dot) == (fam.p_max, 0.0)
    assert st[k].stance != st[k - 1].stance and st[k].t - st[k - 1].t < 0.5e-3, (st[k - 1].t, st[k].t)
    assert HELD in st[k - 1].qp_message          # the period that started there had its p'' held to the rows


def test_that_trial_in_the_map_is_in_range_and_its_paths_agree(mujoco_cut_short):
    """The capability map's record of that trial (its own path: snapshot, early stop) is in range; the run's
    compiled loop equals the objects' periods record for record (bit for bit); from the memory the objects'
    controller had before each of its periods, the compiled period and the Python steps start the period at
    the same (p, p', tau, tau') bit for bit (the limited one included) and take the same decisions."""
    r, settings, push = mujoco_cut_short
    fam, cc = context().family, settings.ctrl_config("both")
    rec = simulate(SimSpec(Cell("both", "forward", 0.65, 0.025), 750.0), settings)
    assert trials.out_of_range(rec, fam.p_min, fam.p_max, cc.tau_dot_min, cc.tau_dot_max) == "", rec
    assert rec["max_p"] == fam.p_max
    seen = []
    compute = AdaptiveController.compute

    def spy(self, t, q, qd, stance, *args):
        seen.append((self.memory.copy(), t, np.array(q), np.array(qd), stance))
        return compute(self, t, q, qd, stance, *args)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(AdaptiveController, "compute", spy)
        objects = runner.run(steps=runs.trial_steps(push, 3), mode="both", pushes=(push,),
                             sim_config=settings.sim_config(), ctrl_config=cc, family=fam, desc=context().desc,
                             compiled_loop=False)
    assert_same_run(r, objects)
    assert len(seen) == len(r.statuses)
    comp, py = AdaptiveController(cc), AdaptiveController(cc)
    py._kernel = None
    held = 0
    for k, (mem, t, q, qd, stance) in enumerate(seen):
        comp.restore(mem)
        py.restore(mem)
        sa = comp.compute(t, q, qd, stance).status
        sb = py.compute(t, q, qd, stance).status
        assert (sa.p, sa.p_dot, sa.tau, sa.tau_dot, sa.qp_status) == (sb.p, sb.p_dot, sb.tau, sb.tau_dot,
                                                                       sb.qp_status), (k, t)
        assert (sa.p, sa.p_dot) == (r.statuses[k].p, r.statuses[k].p_dot), (k, t)
        assert (sa.p_ddot, sa.tau_ddot) == (pytest.approx(sb.p_ddot, rel=1e-9, abs=1e-9),
                                            pytest.approx(sb.tau_ddot, rel=1e-9, abs=1e-9)), (k, t)
        held += sa.p == fam.p_max and sa.p_dot == 0.0
    assert held >= 1, "no period at p's bound: the comparison checks little"
