"""Plant perturbations: applied to the simulator only, exact on the plant's model, a zero
perturbation bit for bit the nominal run, seeded noise reproducible, delay = the state of d periods ago.

Oracles: the plant's mass matrix (total mass in the base's translation row, inertias in the pitch row:
a scale s of every inertia about its centre of mass adds (s - 1) sum I_i, the parallel-axis terms being
unchanged) and its centre of mass (a shift delta of the torso's centre of mass moves the robot's by
m_torso delta / M along the torso), on both engines; the true records of the same run for the delay;
sample statistics for the noise.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import yaml

from biped_model.description import LEFT, load_description
from biped_model.floating import paper_from_urdf, urdf_from_paper
from biped_model.gait_family import GaitFamily
from biped_sim.plant.perturbation import (ZERO, PerturbationError, PlantPerturbation, SensorModel, plant_parameters,
                                    plant_yaml)
from biped_sim.plant.config import load_sim_config
from biped_sim.plant.rigid import Simulator

from helpers import assert_close, assert_same_run

DESC = load_description()
SHORT = 0.03          # [s] of walking for the runs that only need the first periods


@pytest.fixture(scope="module")
def family():
    return GaitFamily.load()


def _run(perturbation=None, max_time=SHORT, steps=1, **kw):
    from biped_controller.closed_loop import runner
    return runner.run(steps=steps, max_time=max_time, perturbation=perturbation, **kw)


# ------------------------------------------------------------------------------------------ validation
BAD = [
    ("torso_mass_scale", 0.0), ("thigh_mass_scale", -1.0), ("shin_inertia_scale", math.nan),
    ("foot_inertia_scale", math.inf), ("torso_com_shift", math.nan), ("noise_q", -1e-3), ("noise_qd", math.inf),
    ("mu", 0.0), ("mu", -0.5), ("delay", -1), ("delay", 1.5), ("delay", True), ("delay", 10**6), ("seed", -3),
    ("seed", 2.0), ("torso_mass_scale", "1.1"), ("noise_q", True), ("touchdown_delayed", 1),
    ("touchdown_delayed", "no"),
]


@pytest.mark.parametrize("field,value", BAD, ids=[f"{f}={v!r}" for f, v in BAD])
def test_invalid_field_named(field, value):
    with pytest.raises(PerturbationError) as e:
        PlantPerturbation(**{field: value})
    assert e.value.field == field
    assert f"'{field}'" in str(e.value)


@pytest.mark.parametrize("field,shift", [("torso_com_shift", 0.4), ("torso_com_shift", -0.3126),
                                         ("thigh_com_shift", 0.21), ("shin_com_shift", -0.25),
                                         ("foot_com_shift", 0.11)])
def test_shift_off_the_link_named_by_apply(field, shift):
    p = PlantPerturbation(**{field: shift})     # valid alone: the link's length is the description's
    with pytest.raises(PerturbationError) as e:
        p.apply(DESC)
    assert e.value.field == field


def test_unknown_field_named():
    with pytest.raises(PerturbationError) as e:
        PlantPerturbation.from_dict({"torso_mass": 1.1})
    assert e.value.field == "torso_mass"
    assert PlantPerturbation.from_dict({"delay": 2}) == PlantPerturbation(delay=2)


def test_simulator_and_runner_reject_before_running():
    with pytest.raises(PerturbationError, match="torso_com_shift"):
        Simulator(DESC, load_sim_config(), perturbation=PlantPerturbation(torso_com_shift=1.0))


# ------------------------------------------------------------------------------------------ the plant
def test_apply_exact_values_and_nominal_untouched():
    p = PlantPerturbation(torso_mass_scale=1.2, thigh_mass_scale=0.9, torso_com_shift=0.02, shin_com_shift=-0.01,
                          foot_com_shift=0.005, torso_inertia_scale=1.3, foot_inertia_scale=0.7, mu=0.4)
    before = dataclasses.asdict(DESC)
    plant = p.apply(DESC)
    assert dataclasses.asdict(DESC) == before
    assert plant.torso.mass == DESC.torso.mass * 1.2 and plant.thigh.mass == DESC.thigh.mass * 0.9
    assert plant.torso.com == DESC.torso.com + 0.02 and plant.shin.com == DESC.shin.com - 0.01
    assert plant.foot.com_forward == 0.005
    assert plant.torso.inertia == DESC.torso.inertia * 1.3 and plant.foot.inertia == DESC.foot.inertia * 0.7
    assert plant.mu == 0.4
    # everything else is the nominal
    for k in ("gravity", "torque_max", "knee_min_flexion", "knee_max_flexion", "source"):
        assert getattr(plant, k) == getattr(DESC, k)
    assert (plant.torso.length, plant.foot.l_min, plant.foot.l_max) == (DESC.torso.length, DESC.foot.l_min, DESC.foot.l_max)
    assert plant.shin.mass == DESC.shin.mass and plant.thigh.inertia == DESC.thigh.inertia
    assert_close(plant.total_mass, DESC.total_mass + 0.2 * DESC.torso.mass - 2 * 0.1 * DESC.thigh.mass, 1e-12, "M")


def test_zero_and_sensing_only_keep_the_description_object():
    assert ZERO.is_zero and ZERO.apply(DESC) is DESC
    p = PlantPerturbation(noise_q=1e-3, delay=2, seed=5)
    assert p.model_is_nominal and not p.sensing_is_perfect and p.apply(DESC) is DESC
    assert PlantPerturbation(seed=9).is_zero
    assert not PlantPerturbation(mu=0.7).is_zero        # an explicit mu is a (possibly equal) plant value


def _random_state(rng):
    x = np.zeros(9)
    x[:2] = rng.uniform(-0.5, 0.5, 2) + np.array([0.0, 0.8])
    x[2:] = rng.uniform(-0.8, 0.8, 7)
    return x


@pytest.mark.parametrize("engine", ["reference", "fast"])
def test_plant_model_built_from_the_perturbed_description(engine):
    """Mass matrix and centre of mass of the simulator's model against hand values of the perturbation."""
    cfg = load_sim_config(engine=engine)
    rng = np.random.default_rng(14)
    nominal = Simulator(DESC, cfg)
    mass = Simulator(DESC, cfg, perturbation=PlantPerturbation(torso_mass_scale=1.2, foot_mass_scale=2.0))
    s_i = 1.3
    inert = Simulator(DESC, cfg, perturbation=PlantPerturbation(
        torso_inertia_scale=s_i, thigh_inertia_scale=s_i, shin_inertia_scale=s_i, foot_inertia_scale=s_i))
    delta = 0.02
    com = Simulator(DESC, cfg, perturbation=PlantPerturbation(torso_com_shift=delta))
    sum_i = DESC.torso.inertia + 2 * (DESC.thigh.inertia + DESC.shin.inertia + DESC.foot.inertia)
    M_plant = DESC.total_mass + 0.2 * DESC.torso.mass + 2 * DESC.foot.mass
    for _ in range(5):
        x = _random_state(rng)
        M0 = nominal.fm.mass_matrix(x)
        assert_close(mass.fm.mass_matrix(x)[0, 0], M_plant, 1e-10, "plant total mass (base x row)")
        assert_close(mass.fm.mass_matrix(x)[1, 1], M_plant, 1e-10, "plant total mass (base z row)")
        assert_close(M0[0, 0], DESC.total_mass, 1e-10, "nominal total mass")
        assert_close(inert.fm.mass_matrix(x)[2, 2] - M0[2, 2], (s_i - 1) * sum_i, 1e-10, "pitch inertia row")
        # torso's axis: up from the hip at pitch theta = x[2] (counter-clockwise): (-sin, cos)
        axis = np.array([-math.sin(x[2]), math.cos(x[2])])
        moved = np.asarray(com.fm.com(x))[:2] - np.asarray(nominal.fm.com(x))[:2]
        assert_close(moved, DESC.torso.mass * delta / DESC.total_mass * axis, 1e-10, "centre of mass shift")


def test_plant_friction_decides_slip():
    """The fall check uses the plant's mu: the same wrench slips on mu 0.3 and not on the nominal 0.7."""
    cfg = load_sim_config()
    w = np.array([0.35 * 400.0, 400.0, 0.0])
    assert Simulator(DESC, cfg)._check_wrench(w, 0.0) is None
    f = Simulator(DESC, cfg, perturbation=PlantPerturbation(mu=0.3))._check_wrench(w, 0.0)
    assert f is not None and f.cause == "slip", f


# ------------------------------------------------------------------------------------------ closed loop
def test_zero_perturbation_reproduces_the_nominal_run_bit_for_bit():
    """A whole first step and the impact: no perturbation, the zero one, and the zero one with a seed."""
    a = _run(None, max_time=None)
    assert a.steps_walked == 1 and not a.fallen
    assert_same_run(a, _run(PlantPerturbation(), max_time=None))
    assert_same_run(a, _run(PlantPerturbation(seed=123), max_time=None))


def test_perturbed_mass_changes_the_dynamics():
    """Negative control: the same comparison fails for a heavier torso; the first decision is the same
    (same measured state) but the ground's reaction to it is not."""
    a = _run(None)
    b = _run(PlantPerturbation(torso_mass_scale=1.2))
    with pytest.raises(AssertionError):
        assert_same_run(a, b)
    assert np.array_equal(a.records[0].torque, b.records[0].torque)
    assert abs(b.records[0].wrench[1] - a.records[0].wrench[1]) > 1.0      # [N]
    assert not np.array_equal(a.records[-1].x, b.records[-1].x)


def test_controller_keeps_the_nominal_model(monkeypatch):
    """runner.run gives the perturbation to the simulator only: the controller's description and both of
    its models (Pinocchio and compiled) have the nominal masses, the simulator's have the plant's."""
    from biped_controller.closed_loop import runner
    made = {}

    make_plant = runner.make_plant

    def spy_plant(*a, **k):     # runner builds its plant through make_plant
        made["sim"] = make_plant(*a, **k)
        return made["sim"]

    class SpyCtrl(runner.AdaptiveController):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made["ctrl"] = self

    monkeypatch.setattr(runner, "make_plant", spy_plant)
    monkeypatch.setattr(runner, "AdaptiveController", SpyCtrl)
    p = PlantPerturbation(torso_mass_scale=1.2, shin_com_shift=0.03, thigh_inertia_scale=0.7, mu=0.5, delay=1)
    runner.run(steps=1, max_time=0.005, perturbation=p, desc=DESC)
    sim, ctrl = made["sim"], made["ctrl"]
    assert ctrl.desc == DESC and ctrl.desc is DESC
    assert_close(ctrl.model.mass, DESC.total_mass, 1e-12, "controller's Pinocchio model mass")
    if ctrl._fast is not None:
        bodies = {b.name: b for b in ctrl._fast.tree.bodies}
        assert bodies["torso"].mass == DESC.torso.mass and bodies["stance_thigh"].inertia == DESC.thigh.inertia
    assert ctrl.model.mu == DESC.mu
    assert sim.nominal_desc is DESC and sim.desc == p.apply(DESC) and sim.desc != DESC
    assert_close(sim.fm.mass, DESC.total_mass + 0.2 * DESC.torso.mass, 1e-12, "plant mass")
    assert sim.desc.mu == 0.5


def test_seeded_noise_is_reproducible():
    p = PlantPerturbation(noise_q=1e-3, noise_qd=2e-2, seed=7)
    a, b = _run(p), _run(p)
    assert_same_run(a, b)
    c = _run(dataclasses.replace(p, seed=8))
    with pytest.raises(AssertionError):
        assert_same_run(a, c)
    # the noise reaches the controller only: the first true state is the nominal one
    n = _run(None)
    assert np.array_equal(a.records[0].x, n.records[0].x)
    assert not np.array_equal(a.statuses[0].margins, n.statuses[0].margins)


def test_noise_statistics_and_identity():
    """Sample mean and standard deviation of the noise the sensors add (12000 draws per signal); the
    identity sensor model returns the true values."""
    p = PlantPerturbation(noise_q=2e-3, noise_qd=5e-2, seed=11)
    s = SensorModel(p)
    q = np.linspace(-0.5, 0.5, 6)
    qd = np.linspace(-2.0, 2.0, 6)
    eq, eqd = [], []
    for k in range(2000):
        _, a, b = s.sample(k, LEFT, q, qd)
        eq.append(a - q)
        eqd.append(b - qd)
    eq, eqd = np.array(eq), np.array(eqd)
    for e, sd, what in ((eq, 2e-3, "q"), (eqd, 5e-2, "qd")):
        assert abs(e.mean()) < 4 * sd / math.sqrt(e.size), what
        assert abs(e.std() / sd - 1.0) < 0.04, (what, e.std())
    # independent of each other and across joints
    assert abs(np.corrcoef(eq[:, 0], eqd[:, 0])[0, 1]) < 0.08
    assert abs(np.corrcoef(eq[:, 0], eq[:, 1])[0, 1]) < 0.08
    # reset: the same sequence again
    s.reset()
    assert np.array_equal(s.sample(0, LEFT, q, qd)[1] - q, eq[0])
    # the same period twice: the same sample
    assert np.array_equal(s.sample(0, LEFT, q, qd)[1] - q, eq[0])
    s.sample(5, LEFT, q, qd)
    with pytest.raises(ValueError):      # the sensors cannot go back in time
        s.sample(3, LEFT, q, qd)


@pytest.mark.parametrize("d,touchdown_delayed", [(1, True), (2, True), (1, False), (3, False)])
def test_delay_controller_sees_the_state_of_d_periods_ago(family, d, touchdown_delayed):
    """Closed loop as runner.run, through the first impact: what the controller is given at period k is
    the true record of period k - d (stance included; the first record while k < d), at the current time;
    once the told stance differs from the true one (a touchdown the controller has not seen yet), the
    torque is applied to the legs the controller meant (mapped with the stance it was told), and the true
    record carries that torque in the true stance's paper order. With ``touchdown_delayed`` False the
    source is max(k - d, the first record of the current stance): the touchdown is told at once."""
    from biped_controller.core.control.config import load_controller_config
    from biped_controller.core.control.controller import AdaptiveController
    cfg = load_sim_config()
    sim = Simulator(DESC, cfg, perturbation=PlantPerturbation(delay=d, touchdown_delayed=touchdown_delayed))
    ctrl = AdaptiveController(load_controller_config(mode="both", period=cfg.control_period), family, DESC)
    q0, qd0 = family.initial_state()
    sim.reset(q0, qd0, LEFT)
    ctrl.reset(LEFT)
    obs, recs, cmds = [], [], []
    first_after_impact = None
    while True:
        o = sim.observe()
        out = ctrl.compute(o.t, o.q, o.qd, o.stance)
        r = sim.step(out.torque)
        obs.append(o)
        recs.append(r)
        cmds.append(out.torque)
        if first_after_impact is None and r.impacts >= 1:
            first_after_impact = len(recs) - 1
        if r.fallen or (first_after_impact is not None and len(recs) > first_after_impact + d + 1):
            break
        assert sim.t < 1.0, "no touchdown within 1 s"
    assert sim.impact_count >= 1
    mismatched = 0
    for k, (o, r) in enumerate(zip(obs, recs)):
        j = max(k - d, 0)
        if not touchdown_delayed and k >= first_after_impact:
            j = max(j, first_after_impact)
        src = recs[j]
        assert o.t == r.t and o.step == r.step
        assert o.stance == src.stance and np.array_equal(o.q, src.q) and np.array_equal(o.qd, src.qd), k
        lo, hi = (np.array(v) for v in DESC.torque_limits())
        cmd = np.clip(cmds[k], lo, hi)
        if o.stance == r.stance:
            assert np.array_equal(r.torque, cmd)
        else:
            mismatched += 1
            assert_close(r.torque, paper_from_urdf(urdf_from_paper(cmd, o.stance), r.stance), 1e-12, "torque")
    if touchdown_delayed:
        assert mismatched >= 1      # the loop did cover the delayed touchdown
    else:
        assert mismatched == 0 and not recs[-1].fallen and len(recs) == first_after_impact + d + 2
        assert obs[first_after_impact + d].step == recs[first_after_impact + d].step
        assert np.array_equal(obs[first_after_impact + d - 1].q, recs[first_after_impact].q)   # held sample


def test_torque_function_refused_with_a_sensor_model(family):
    sim = Simulator(DESC, load_sim_config(), perturbation=PlantPerturbation(noise_q=1e-3))
    q0, qd0 = family.initial_state()
    sim.reset(q0, qd0, LEFT)
    with pytest.raises(PerturbationError):
        sim.step(lambda s, q, qd, st: np.zeros(6))


# ------------------------------------------------------------------------------------------ records
def test_plant_parameters_yaml_round_trip():
    p = PlantPerturbation(torso_mass_scale=1.1, torso_com_shift=-0.02, noise_qd=0.01, delay=2, seed=3, mu=0.5)
    doc = yaml.safe_load(plant_yaml(DESC, p))
    assert doc == plant_parameters(DESC, p)
    assert_close(doc["plant"]["torso"]["mass"], 1.1 * DESC.torso.mass, 1e-12, "torso mass")
    assert_close(doc["plant"]["torso"]["com_from_proximal"], DESC.torso.com - 0.02, 1e-12, "torso com")
    assert doc["plant"]["mu"] == 0.5 and doc["nominal"]["mu"] == DESC.mu
    assert doc["sensing"]["delay_periods"] == 2 and doc["perturbation"] == p.as_dict()
    assert PlantPerturbation.from_dict(doc["perturbation"]) == p
    assert set(doc["changed"]) == {"torso_mass_scale", "torso_com_shift", "noise_qd", "delay", "mu", "seed"}
    assert doc["sensing"]["touchdown_delayed"] is True


def test_experiment_settings_carry_the_perturbation():
    """The experiments' RunSettings pass it to the simulator and into the capability map's fingerprint;
    the nominal settings' description (and so every existing store) is unchanged."""
    from biped_controller.studies import capability_map as cmap
    from biped_controller.studies.trial.settings import RunSettings
    p = PlantPerturbation(delay=1)
    assert "perturbation" not in RunSettings().describe()
    assert "perturbation" not in RunSettings(perturbation=ZERO).describe()
    assert RunSettings(perturbation=p).describe()["perturbation"]["delay"] == 1
    f0 = cmap.fingerprint(cmap.MapSpec(settings=RunSettings()))
    assert f0 == cmap.fingerprint(cmap.MapSpec(settings=RunSettings(perturbation=ZERO)))
    assert f0 != cmap.fingerprint(cmap.MapSpec(settings=RunSettings(perturbation=p)))


# ------------------------------------------------------------------------------------------ simulator node
def _node_cmd(*params):
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    cmd = [str(root / ".venv" / "lib" / "biped_sim" / "simulator"), "--ros-args", "--params-file",
           str(root / "config" / "graph.yaml")]
    for p in params:
        cmd += ["-p", p]
    return cmd, root


NODE_BAD = [("perturbation.torso_mass_scale:=-1.0", "perturbation.torso_mass_scale"),
            ("perturbation.torso_com_shift:=0.5", "perturbation.torso_com_shift"),
            ("perturbation.delay:=-1", "perturbation.delay"),
            ("perturbation.noise_qd:=-0.1", "perturbation.noise_qd"),
            ("perturbation.mu:=-0.2", "perturbation.mu"),
            ("perturbation.touchdown_delayed:=3", "perturbation.touchdown_delayed")]


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize("param,named", NODE_BAD, ids=[n for _, n in NODE_BAD])
def test_node_rejects_a_bad_perturbation_naming_it(ros_domain, param, named):
    import subprocess
    cmd, root = _node_cmd(param)
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=root)
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    assert f"invalid parameter '{named}'" in r.stderr, r.stderr[-2000:]


@pytest.mark.ros
@pytest.mark.slow
def test_node_publishes_the_plant_latched(rclpy_context):
    """/sim/plant (transient local) carries the plant's parameters of the node's perturbation, received by
    a late subscriber before any controller exists."""
    import subprocess
    import time
    from rclpy.node import Node
    from std_msgs.msg import String
    from biped_sim.graph import names as gn
    cmd, root = _node_cmd("perturbation.torso_mass_scale:=1.2", "perturbation.delay:=2", "perturbation.mu:=0.5",
                          "perturbation.noise_q:=0.001", "perturbation.seed:=4", "perturbation.touchdown_delayed:=false",
                          "start_timeout:=60.0")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=root)
    got = []
    try:
        time.sleep(2.0)                      # subscribe late: the message was published at start
        node = Node("plant_probe", context=rclpy_context)
        node.create_subscription(String, gn.SIM_PLANT, lambda m: got.append(m.data), gn.TOPICS[gn.SIM_PLANT].qos_profile)
        from rclpy.executors import SingleThreadedExecutor
        ex = SingleThreadedExecutor(context=rclpy_context)
        ex.add_node(node)
        deadline = time.monotonic() + 60
        while not got and time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()[1][-2000:]
            ex.spin_once(timeout_sec=0.1)
        ex.shutdown()
        node.destroy_node()
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    assert got, "no /sim/plant message"
    doc = yaml.safe_load(got[0])
    p = PlantPerturbation(torso_mass_scale=1.2, delay=2, mu=0.5, noise_q=0.001, seed=4, touchdown_delayed=False)
    assert doc == plant_parameters(DESC, p)
    assert_close(doc["plant"]["torso"]["mass"], 24.0, 1e-12, "plant torso mass")


# ------------------------------------------------------------------------------------------ robustness table
def _synthetic_task(batch, settings, height):
    """Survival below 333 N and on an island 600-640 N (no simulation): the capability map's record."""
    out = []
    for s in batch:
        c = s.cell
        ok = s.force < 333.0 or 600.0 <= s.force <= 640.0
        out.append({"mode": c.mode, "direction": c.direction, "phase": c.phase, "duration": c.duration,
                    "force": s.force, "start": 0.2315, "signed_force": s.force, "height": height, "survived": ok,
                    "reason": "survived" if ok else "fell: tip_toe at t = 0.3 s", "cause": "" if ok else "tip_toe",
                    "fall_time": None if ok else 0.3, "steps_walked": 11 if ok else 0})
    return out


def test_stored_max_push_replays_the_capability_map_search(tmp_path):
    """The table's report from a store alone equals the capability map's own search on the same records;
    an unfinished search, or records of another perturbation (another fingerprint), give nothing."""
    from biped_controller.studies import capability_map as cmap
    from biped_controller.studies import robustness as rb
    spec = rb.push_spec(PlantPerturbation(torso_mass_scale=0.9), "both", True)
    store = cmap.RecordStore(tmp_path / "push.jsonl")
    run = cmap.run_map(spec, cmap.SerialExecutor(_synthetic_task), store)
    live = rb.max_push_record(run)
    assert live["max_force"] == 320.0 and live["first_failure"] == 340.0 and live["cause"] == "tip_toe"
    assert live["islands"] == [600.0, 640.0]
    assert live["max_force_no_fall"] == 320.0 and live["first_fall"] == 340.0
    # a failure without a fall (not back on the gait) is no fall: the no-fall edge moves up, bisected too
    def unsettled(batch, settings, height):
        out = _synthetic_task(batch, settings, height)
        for r in out:
            if not r["survived"] and r["force"] < 500.0:
                r.update(reason="tau' = 0.97 not back to 1 (> 0.001)", cause="tau_dot_not_back", fall_time=None)
        return out
    up = rb.max_push_record(cmap.run_map(spec, cmap.SerialExecutor(unsettled)))
    assert up["max_force"] == 320.0 and up["cause"] == "tau_dot_not_back"
    assert up["max_force_no_fall"] < 500.0 <= up["first_fall"] and up["first_fall"] - up["max_force_no_fall"] <= 20.0
    stored = rb.stored_max_push(spec, store.load())
    assert {k: stored[k] for k in live} == live
    recs = store.load()
    assert rb.stored_max_push(spec, [r for r in recs if r["force"] != 340.0]) is None   # the bisection step
    other = rb.push_spec(PlantPerturbation(torso_mass_scale=1.1), "both", True)
    assert rb.stored_max_push(other, recs) is None


@pytest.mark.ros
@pytest.mark.slow
def test_recorded_perturbed_run_carries_the_true_plant_in_the_bag_metadata(ros_domain, tmp_path):
    """The whole graph with a heavier torso: the bag holds the plant both as the latched /sim/plant and as
    the MCAP metadata record 'biped_plant' (read with the mcap package, not the project's reader)."""
    import subprocess
    import sys
    import yaml
    from mcap.reader import make_reader
    from biped_sim.graph.recorder_node import PLANT_METADATA
    from biped_model.settings import repo_root
    bag = tmp_path / "bag"
    r = subprocess.run([sys.executable, "-m", "biped_sim.graph.launch", "--bag", str(bag), "--steps", "1",
                        "--sim-param", "perturbation.torso_mass_scale:=1.1"],
                       capture_output=True, text=True, timeout=300, cwd=repo_root())
    assert r.returncode == 0, r.stderr[-3000:]
    (mcap_file,) = bag.glob("*.mcap")
    with open(mcap_file, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    plant = yaml.safe_load(meta[PLANT_METADATA]["yaml"])
    text = meta[PLANT_METADATA]["yaml"]
    nominal = DESC.torso.mass
    assert f"{1.1 * nominal}" in text or any(
        abs(v - 1.1 * nominal) < 1e-9 for v in _numbers(plant)), text[:2000]


def _numbers(tree):
    """Every number in a nested YAML tree."""
    if isinstance(tree, dict):
        for v in tree.values():
            yield from _numbers(v)
    elif isinstance(tree, list):
        for v in tree:
            yield from _numbers(v)
    elif isinstance(tree, (int, float)) and not isinstance(tree, bool):
        yield float(tree)
