"""The MuJoCo plant: model equivalence with Pinocchio, the contact's forces read two ways, the
switch, a walk, sensed touchdown against the geometric contact, a physical fall, the records' momentum
balance, the stance ankle measured against the ground, and the rigid plant's records unchanged."""
from __future__ import annotations

import dataclasses
import hashlib
import math

import numpy as np
import pinocchio as pin
import pytest

from biped_sim.plant.config import SimConfigError, load_sim_config
from biped_sim.plant.push import Push
from biped_model.description import LEFT, RIGHT, load_description
from biped_model.floating import FloatingModel

mujoco = pytest.importorskip("mujoco")

MJ = load_sim_config(plant="mujoco")


def _plant(desc=None, **over):
    from biped_sim.plant.mujoco import MujocoPlant
    return MujocoPlant(desc, load_sim_config(plant="mujoco", **over))


# ------------------------------------------------------------------------------------------ model
@pytest.mark.parametrize("seed", [0, 1])
def test_mass_matrix_com_and_bias_match_pinocchio(seed):
    """M(x), the centre of mass and the bias forces h(x, v) (gravity alone at v = 0) of the generated MJCF
    against the Pinocchio floating model (URDF), at seeded random configurations and velocities."""
    desc = load_description()
    p = _plant(desc)
    fm = FloatingModel(desc)
    m, d = p.model, p.data
    assert sum(m.body_mass) == pytest.approx(desc.total_mass, abs=1e-12)
    rng = np.random.default_rng(seed)
    M = np.zeros((9, 9))
    for _ in range(10):
        x = np.concatenate([rng.uniform(-1, 1, 2), rng.uniform(-math.pi, math.pi, 7)])
        v = rng.normal(0.0, 2.0, 9)
        d.qpos[:], d.qvel[:] = x, 0.0
        mujoco.mj_forward(m, d)
        mujoco.mj_fullM(m, d, M)
        assert np.max(np.abs(M - fm.mass_matrix(x))) < 1e-12
        assert np.max(np.abs(d.subtree_com[p._torso] - pin.centerOfMass(fm.model, fm.data, x))) < 1e-14
        assert np.max(np.abs(d.qfrc_bias - pin.computeGeneralizedGravity(fm.model, fm.data, x))) < 1e-11
        d.qvel[:] = v
        mujoco.mj_forward(m, d)
        assert np.max(np.abs(d.qfrc_bias - pin.nonLinearEffects(fm.model, fm.data, x, v))) < 1e-10
        for foot in (LEFT, RIGHT):      # the foot frames: ankle position and pitch
            pose = fm.foot_pose(x, foot)
            b = d.xpos[p._foot_body[foot]]
            assert abs(b[0] - pose[0]) < 1e-14 and abs(b[2] - pose[1]) < 1e-14
            assert abs(p.foot_pitch(x, foot) - pose[2]) < 1e-14


def test_model_check_catches_a_different_robot():
    """Negative control: a plant built from a heavier torso does not pass the comparison above."""
    desc = load_description()
    heavy = dataclasses.replace(desc, torso=dataclasses.replace(desc.torso, mass=desc.torso.mass * 1.01))
    p = _plant(heavy)
    fm = FloatingModel(desc)
    x = np.random.default_rng(3).uniform(-1, 1, 9)
    p.data.qpos[:] = x
    mujoco.mj_forward(p.model, p.data)
    M = np.zeros((9, 9))
    mujoco.mj_fullM(p.model, p.data, M)
    assert np.max(np.abs(M - fm.mass_matrix(x))) > 0.1


# ------------------------------------------------------------------------------------------ switch
def test_the_switch_and_its_errors():
    from biped_sim.plant.protocol import PLANTS, Plant, PlantError, make_plant
    from biped_controller.studies.trial import settings as ts
    assert PLANTS == ("rigid", "mujoco")
    assert load_sim_config().plant == "rigid"          # the rigid plant stays the default
    p = make_plant("mujoco", config=MJ)
    assert isinstance(p, Plant) and type(p).__name__ == "MujocoPlant"
    with pytest.raises(PlantError, match="plant must be one of"):
        make_plant("bullet")
    with pytest.raises(SimConfigError, match="plant must be one of"):
        load_sim_config(plant="bullet")
    with pytest.raises(SimConfigError, match="mujoco_timestep must divide control_period"):
        load_sim_config(plant="mujoco", mujoco_timestep=0.0003)
    assert load_sim_config(control_period=0.0013).control_period == 0.0013   # the rigid plant: any period
    with pytest.raises(SimConfigError, match="mujoco_cone"):
        load_sim_config(mujoco_cone="round")
    with pytest.raises(SimConfigError, match="mujoco_touch_threshold"):
        load_sim_config(mujoco_touch_threshold=-1.0)
    st = ts.parse_overrides(["plant=mujoco"])
    assert st.sim_config().plant == "mujoco"


# ------------------------------------------------------------------------------------------ contact
def test_contact_forces_three_ways_agree():
    """The per-foot wrench and the body-contact test of the plant's compiled step bookkeeping
    (``mujoco_kernels.after_step``) equal, bit for bit, the Python reference ``MujocoPlant._contacts``
    (MuJoCo's per-body external forces), and within 1e-9 of the largest normal force the rows summed over
    MuJoCo's contact list and its constraint forces (``contacts_from_list``), after every MuJoCo step of the
    first step of a walk with a push (landing included). Negative control: the two feet's rows, swapped,
    do not agree (the comparison sees the loads)."""
    from biped_controller.closed_loop import runner
    from biped_sim.plant import mujoco as pm
    mk = pm.load_kernels()
    seen = []

    def probe(plant):
        k = plant._acc[mk.A_ROWS:mk.A_ROWS + 8].reshape(2, 4)
        khit = int(plant._acc[mk.A_HIT])
        a, ha = plant._contacts()
        b, hb = plant.contacts_from_list()
        seen.append((np.array_equal(k, np.array(a)) and khit == ha, np.max(np.abs(k - b)), khit == hb,
                     max(b[0][3], b[1][3]), np.max(np.abs(k[::-1] - b))))
    orig = pm.MujocoPlant.reset

    def reset(self, *a, **kw):
        self.probe = probe
        return orig(self, *a, **kw)
    mp = pytest.MonkeyPatch()
    mp.setattr(pm.MujocoPlant, "reset", reset)
    try:
        r = runner.run(steps=1, mode="both", sim_config=MJ, pushes=(Push(0.2315, 0.025, 200.0),))
    finally:
        mp.undo()
    assert r.steps_walked == 1 and len(seen) >= 900      # 2 MuJoCo steps per period, 0.45 s
    assert all(s[0] for s in seen)
    fmax = max(s[3] for s in seen)
    assert fmax > 300.0
    assert max(s[1] for s in seen) < 1e-9 * fmax
    assert all(s[2] for s in seen)
    assert max(s[4] for s in seen) > 100.0           # swapped feet: caught


def test_observed_stance_ankle_is_measured_against_the_ground():
    """q1 (q1') reported = the stance ankle encoder + the stance foot's pitch (rate); the records keep the
    encoders. A flat foot: the same numbers as the rigid convention."""
    from biped_model.gait_family import GaitFamily
    p = _plant()
    q0, qd0 = GaitFamily.load().initial_state()
    p.reset(q0, qd0, LEFT)
    o = p.observe()
    assert np.max(np.abs(o.q - q0)) < 1e-12 and np.max(np.abs(o.qd - qd0)) < 1e-12
    x, v = p.x.copy(), p.v.copy()
    x[2] += 0.01      # tilt the whole robot by 0.01 rad: the stance foot pitches by 0.01, the encoders not
    v[2] += 0.3
    p.x, p.v = x, v
    o = p.observe()
    assert o.q[0] == pytest.approx(q0[0] + 0.01, abs=1e-12) and o.qd[0] == pytest.approx(qd0[0] + 0.3, abs=1e-12)
    assert np.max(np.abs(o.q[1:] - q0[1:])) < 1e-12
    rec = p.step(np.zeros(6))
    assert rec.q[0] == pytest.approx(q0[0], abs=1e-12)     # the record: the true encoder


# ------------------------------------------------------------------------------------------ walking
@pytest.fixture(scope="module")
def walk20():
    from biped_controller.closed_loop import runner
    from biped_sim.plant import mujoco as pm
    plants = []
    orig = pm.MujocoPlant.reset

    def reset(self, *a, **k):
        self.trace = []
        plants.append(self)
        return orig(self, *a, **k)
    mp = pytest.MonkeyPatch()
    mp.setattr(pm.MujocoPlant, "reset", reset)
    try:
        r = runner.run(steps=20, mode="both", sim_config=MJ)
    finally:
        mp.undo()
    return r, plants[0]


def test_twenty_steps_in_mode_both_survive(walk20):
    from biped_controller.closed_loop import runner
    r, plant = walk20
    assert not r.fallen and r.steps_walked == 20, (r.fall_cause, r.fall_detail)
    assert [i.new_stance for i in r.impacts] == [RIGHT, LEFT] * 10
    rigid = runner.run(steps=20, mode="both")
    # step times: the sensed touchdowns fall within 2 ms of the rigid plant's (0.46296 s): same gait
    steps = np.diff([0.0] + [i.t for i in r.impacts])
    rsteps = np.diff([0.0] + [i.t for i in rigid.impacts])
    assert np.max(np.abs(steps - rsteps)) < 2e-3, (steps, rsteps)
    # the soft foot is not the rigid foot: it rolls a little, never past the fall angle
    assert 0.0 < plant.diagnostics.max_tilt < MJ.mujoco_fall_foot_tilt


def test_sensed_touchdown_within_2ms_of_the_geometric_contact(walk20):
    """The geometric contact, from the logged MuJoCo states and Pinocchio's kinematics (not MuJoCo's
    collision): the instant the landing foot's lowest sole point reaches z = 0 (linear between samples)."""
    r, plant = walk20
    fm = FloatingModel()
    T = np.array([t for t, _ in plant.trace])
    low = {foot: np.array([np.min(fm.sole_points(x, foot)[:, 1]) for _, x in plant.trace]) for foot in (LEFT, RIGHT)}
    lags = []
    prev = 0.0
    for imp in r.impacts:
        z = low[imp.new_stance]
        sel = np.nonzero((T > prev + 0.1) & (T <= imp.t + 1e-12))[0]   # this swing phase (0.1 s after the last)
        k = sel[np.argmax(z[sel] <= 0.0)]
        assert z[k] <= 0.0 < z[k - 1]
        t_geo = T[k - 1] + (T[k] - T[k - 1]) * z[k - 1] / (z[k - 1] - z[k])
        lags.append(imp.t - t_geo)
        prev = imp.t
    lags = np.array(lags)
    assert np.all(lags >= 0.0) and np.all(lags <= 2e-3), lags
    # negative control of the check: a touchdown reported two control periods and a half later would fail it
    late = lags + 2.5e-3
    assert not np.all(late <= 2e-3)
    assert np.max(lags) <= plant.cfg.mujoco_timestep * 2 + 1e-12     # measured: within one or two MuJoCo steps


def test_period_momentum_balances_the_recorded_wrench_push_and_impacts(walk20):
    """P(t_end) - P(t) = (F_x dt + push impulse, (F_z - M g) dt) + the impact's impulse when the period ends in
    a touchdown, with the records' period-mean wrench (Pinocchio's centre-of-mass Jacobian for P). Negative
    control: the wrench of the period before leaves residuals 100x larger."""
    r, _ = walk20
    fm = FloatingModel()
    Mg = fm.mass * fm.desc.gravity
    imp = {i.t: i for i in r.impacts}

    def P(x, v):
        return fm.mass * (pin.jacobianCenterOfMass(fm.model, fm.data, x) @ v)[[0, 2]]

    def residuals(shift):
        out = []
        for k in range(1 + shift, len(r.records) - 1):
            a, b = r.records[k], r.records[k + 1]
            w = r.records[k - shift].wrench
            dt = a.t_end - a.t
            J = imp[a.t_end].impulse[:2] if a.t_end in imp else 0.0
            out.append(P(b.x, b.v) - P(a.x, a.v) - (np.array([w[0] * dt + a.push_impulse, (w[1] - Mg) * dt]) + J))
        return np.abs(np.array(out))
    good, bad = residuals(0), residuals(1)
    assert np.max(good) < 0.02            # O(h^2) of the discrete centre-of-mass velocity; 0.4 N s per period
    assert np.median(good) < 1e-3
    assert np.max(bad) > 100 * np.max(good)


# ------------------------------------------------------------------------------------------ falls
def test_a_push_far_above_the_boundary_ends_in_a_physical_fall():
    """1500 N for 25 ms (the rigid plant's boundary in mode both is about 550 N): the MuJoCo plant's run ends in
    a physical fall, with its cause, after the push began; the rigid plant declares a contact limit."""
    from biped_controller.closed_loop import runner
    push = (Push(0.2315, 0.025, 1500.0),)
    r = runner.run(steps=4, mode="both", sim_config=MJ, pushes=push)
    assert r.fallen and r.fall_cause in ("body_contact", "hip_low", "foot_rotated"), r.fall_cause
    assert r.fall_time > 0.2315 and r.fall_detail
    assert r.records[-1].fallen and r.records[-1].fall_cause == r.fall_cause
    rigid = runner.run(steps=4, mode="both", pushes=push)
    assert rigid.fallen and rigid.fall_cause in ("tip_toe", "tip_heel", "slip", "take_off")
    # without the push the same run walks: the fall is the push's
    free = runner.run(steps=1, mode="both", sim_config=MJ)
    assert not free.fallen


def test_fall_checks_each_fire(monkeypatch):
    """Each physical check on a state built for it: hip low, foot rotated, a shin on the floor."""
    from biped_model.gait_family import GaitFamily
    p = _plant()
    q0, qd0 = GaitFamily.load().initial_state()
    p.reset(q0, qd0, LEFT)
    x = p.x.tolist()
    assert p._check_fall(0.0, x, -1) is None
    low = list(x)
    low[1] = MJ.mujoco_fall_hip_height - 1e-3
    assert p._check_fall(0.0, low, -1).cause == "hip_low"
    tilted = list(x)
    tilted[5] += 1.1 * MJ.mujoco_fall_foot_tilt      # left ankle: the stance foot pitches
    assert p._check_fall(0.0, tilted, -1).cause == "foot_rotated"
    # a shin on the floor: MuJoCo's own contact (the capsule below z = 0)
    xs = p.x.copy()
    xs[1] = 0.2        # hip at 0.2 m: the legs' capsules go through the floor
    p.data.qpos[:] = xs
    p.data.qvel[:] = 0.0
    mujoco.mj_forward(p.model, p.data)
    _, hit = p._contacts()
    assert hit >= 0 and p._check_fall(0.0, xs.tolist(), hit).cause == "body_contact"


# ------------------------------------------------------------------------------------------ rigid unchanged
# status fields added after these digests were taken (the whole-body stage's status, constant
# outside modes wbc / hybrid; the torso parameter's, 0 outside modes lambda / all); every other field of
# every record is hashed
_NEWER_FIELDS = ("wbc_status", "wbc_active", "wbc_deviation", "lam", "lam_dot", "lam_ddot", "lam_ddot_star")


def _h(h, o):
    if dataclasses.is_dataclass(o):
        for f in dataclasses.fields(o):
            if f.name in _NEWER_FIELDS:
                continue
            h.update(f.name.encode())
            _h(h, getattr(o, f.name))
    elif isinstance(o, np.ndarray):
        h.update(np.ascontiguousarray(o, dtype=float).tobytes())
    elif isinstance(o, (list, tuple)):
        for x in o:
            _h(h, x)
    elif isinstance(o, float):
        h.update(np.float64(o).tobytes())
    else:
        h.update(repr(o).encode())


@pytest.mark.parametrize("name,kw,digest", [
    ("walk-both", dict(steps=3, mode="both"), "d74cc794271b7a8a"),
    ("push900-both-fall", dict(steps=4, mode="both", pushes=(Push(start=0.2315, duration=0.025, force=900.0),)),
     "c6e3fa524ada573d"),
])
def test_rigid_plant_records_bit_identical(name, kw, digest):
    """The rigid plant's records, statuses and impacts hash as before the MuJoCo plant (the team's fingerprint
    of the restructured main, commit bfdaaa8): the second engine changed nothing of the first."""
    from biped_controller.closed_loop import runner
    r = runner.run(**kw)
    h = hashlib.sha256()
    _h(h, r.records)
    _h(h, r.statuses)
    _h(h, r.impacts)
    h.update(repr((r.steps_walked, r.fallen, r.fall_cause, r.fall_detail, r.fall_time)).encode())
    assert h.hexdigest()[:16] == digest


def test_robustness_set_reaches_every_run(monkeypatch, capsys):
    """scripts/robustness --set plant=mujoco: the walks' and pushes' settings carry it (and so their stored
    records' fingerprint: a rigid record is never reused for MuJoCo); controller keys are refused."""
    from biped_sim.plant.perturbation import PlantPerturbation
    from biped_controller.studies import robustness as rb
    zero = PlantPerturbation()
    rigid_fp = rb.walk_fingerprint(zero, True)
    monkeypatch.setattr(rb, "SIMULATOR_OVERRIDES", (("plant", "mujoco"),))
    assert rb.settings_for(zero, True).sim_config().plant == "mujoco"
    assert rb.push_spec(zero, "both", True).settings.sim_config().plant == "mujoco"
    assert rb.walk_fingerprint(zero, True) != rigid_fp
    with pytest.raises(SystemExit):
        rb.main(["--set", "Kp=3", "--report-only"])
    assert "only config/simulator.yaml keys" in capsys.readouterr().err


# the digests of plant_compare.FINGERPRINT_RUNS (box sole, mujoco_sole_points 0, 0.5 ms MuJoCo steps) with the plant's pure-Python step (main 1752382's
# plant/mujoco.py put in place of the compiled one, the rest of the code this branch merged with main; the
# total `plant_compare fingerprint` d134575e... is the same with either; on 9b97d77 both gave eabdf4b7...);
# machine-specific, as the rigid plant's above
MUJOCO_DIGESTS = {
    "walk-both": "52f5edce62f7b572218df441e6b862f91746ec3a09b2892c2f17bf1dfb45c3dd",
    "delay-both": "eb79b4e57d856a9a5de579de75ee98a93307b624148ea720eb4140a25621765f",
}


@pytest.mark.parametrize("name", sorted(MUJOCO_DIGESTS))
def test_mujoco_records_bit_identical_to_the_python_step(name):
    """Every field of every record, status and impact and the contact diagnostics of a 4-step walk, and of a
    3-step walk with the touchdown reported one period late (the told and the true stance differ for a period
    after each touchdown), hash as with the plant's former pure-Python step: the compiled bookkeeping
    (mujoco_kernels) changes no bit. Negative control: one record's torque changed by one ulp changes the hash."""
    from biped_controller.studies import plant_compare, fingerprint
    spec = next(s for s in plant_compare.FINGERPRINT_RUNS if s[0] == name)
    # the sole and step these digests were taken with: the box (mujoco_sole_points 0; the default sole since is
    # points) and 0.5 ms MuJoCo steps (the default since is 0.125 ms)
    digest, r = plant_compare.run_digest(spec, load_sim_config(plant="mujoco", mujoco_sole_points=0,
                                                               mujoco_timestep=0.0005))
    assert digest == MUJOCO_DIGESTS[name]
    a = fingerprint.digest(r, ())
    rec = r.records[len(r.records) // 2]
    rec.torque[0] = np.nextafter(rec.torque[0], np.inf)
    assert fingerprint.digest(r, ()) != a
