"""The node graph over real DDS with the MuJoCo plant (``--sim-param plant:=mujoco``): the graph runs
unchanged, the bag decodes with readers that are not the project's (``mcap`` + ``mcap_ros2`` in Python, and
Foxglove's npm libraries when node is installed), and its physics is checkable from the bag alone: per period,
the momentum change of the state (base from ``/sim/state``, joints from ``/joint_states``: the encoders) equals
the recorded ground wrench, push and impact impulses; ``/sim/state`` reports q1 against the ground."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PY = ROOT / ".venv" / "bin" / "python"
JS_DIR = Path(__file__).resolve().parent / "js"
STEPS = 2

pytestmark = [pytest.mark.ros, pytest.mark.slow]


@pytest.fixture(scope="module")
def mujoco_bag(tmp_path_factory):
    pytest.importorskip("mujoco")
    mp = pytest.MonkeyPatch()
    from domain_coordinator import domain_id
    dom = domain_id()
    did = dom.__enter__()
    try:
        mp.setenv("ROS_DOMAIN_ID", str(did))
        mp.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        mp.delenv("ROS_STATIC_PEERS", raising=False)
        tmp = tmp_path_factory.mktemp("mujoco_graph")
        bag = tmp / "bag"
        cmd = [str(PY), "-m", "biped_sim.graph.launch", "--bag", str(bag), "--steps", str(STEPS),
               "--sim-param", "plant:=mujoco"]
        proc = subprocess.run(cmd, env=dict(os.environ), cwd=ROOT, capture_output=True, text=True, timeout=600)
        yield bag, proc
    finally:
        dom.__exit__(None, None, None)
        mp.undo()


def _joints_of(js) -> np.ndarray:
    from biped_model.description import URDF_JOINTS
    pos, vel = dict(zip(js.name, js.position)), dict(zip(js.name, js.velocity))
    return np.array([pos[j] for j in URDF_JOINTS]), np.array([vel[j] for j in URDF_JOINTS])


def test_graph_runs_on_mujoco_and_the_bag_decodes(mujoco_bag):
    import bag_physics as bp
    bag, proc = mujoco_bag
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    assert "plant mujoco" in proc.stdout + proc.stderr
    B = bp.load_bag(bag)     # mcap + mcap_ros2 only
    states = bp.states(B)
    n = len(states)
    assert n > 900 and len(B["/sim/impacts"]) == STEPS
    for topic in ("/clock", "/tf", "/stance", "/controller/torque", "/controller/status"):
        assert len(B[topic]) == n, topic
    for topic in ("/joint_states", "/ground_reaction", "/ground_reaction/cop", "/sim/push"):
        assert len(B[topic]) == n - 1, topic
    assert not any(s.fallen for s in states)
    # the recorder's own summary (the soak's checks) finds nothing wrong
    from biped_sim.recording.bag_summary import analyze_bag
    a = analyze_bag(bag)
    assert a["problems"] == [], a["problems"]
    if shutil.which("node") is None or not (JS_DIR / "node_modules" / "@mcap" / "core").is_dir():
        pytest.skip("node or tests/js/node_modules absent: the Python reader alone checked the bag")
    mcap_file = sorted(Path(bag).glob("*.mcap"))[0]
    js = subprocess.run(["node", str(JS_DIR / "read_bag.mjs"), str(mcap_file)], capture_output=True, text=True,
                        timeout=300, cwd=JS_DIR)
    assert js.returncode == 0, js.stderr[-2000:]
    out = json.loads(js.stdout)
    counts = {t: len(v) for t, v in B.items()}
    assert {t: int(c) for t, c in out["counts"].items()} == counts


def test_mujoco_bag_physics_from_the_bag_alone(mujoco_bag):
    """Own planar model (tests/bag_physics, robots/biped7/description.yaml): per period P(t_k+1) - P(t_k) = (F_x dt + push,
    (F_z - M g) dt) + the touchdown's impulse, with /ground_reaction the period's mean wrench (DESIGN.md: the
    MuJoCo plant's instants); every impact: its window is the period it ends, and its impulse is the momentum
    jump over that period less the stance reaction and gravity; /sim/state's q1 = encoder + stance foot pitch."""
    import bag_physics as bp
    bag, proc = mujoco_bag
    assert proc.returncode == 0
    B = bp.load_bag(bag)
    model = bp.PlanarBiped()
    S = bp.states(B)
    js = {bp.ns(m.header.stamp): m for m in B["/joint_states"]}
    wrench = {bp.ns(m.header.stamp): m.wrench.force for m in B["/ground_reaction"]}
    push = {bp.ns(m.stamp): m for m in B["/sim/push"]}
    impact = {bp.ns(m.stamp): m for m in B["/sim/impacts"]}
    Mg = model.mass * model.gravity

    def state(k):
        """Floating (x, v): base from /sim/state, joints from /joint_states (the encoders) at the same stamp."""
        s = S[k]
        m = js[bp.ns(s.stamp)]
        j, jd = _joints_of(m)
        return np.concatenate([np.array(s.base), j]), np.concatenate([np.array(s.base_dot), jd])

    res, jumps = [], []
    for k in range(len(S) - 2):          # the last state has no /joint_states of its own
        t0, t1 = bp.ns(S[k].stamp), bp.ns(S[k + 1].stamp)
        dt = push[t0].period
        assert abs(t0 + dt * 1e9 - t1) <= 1.0
        x0, v0 = state(k)
        x1, v1 = state(k + 1)
        f = wrench[t0]
        J = np.array(impact[t1].impulse[:2]) if t1 in impact else np.zeros(2)
        dP = model.momentum(x1, v1) - model.momentum(x0, v0)
        res.append(dP - (np.array([f.x * dt + push[t0].impulse, (f.z - Mg) * dt]) + J))
        if t1 in impact:
            imp = impact[t1]
            # the impact's window is this period: its states are the period's ends
            assert np.max(np.abs(np.array(imp.x_minus) - x0)) < 1e-12 and np.max(np.abs(np.array(imp.x_plus) - x1)) < 1e-12
            jumps.append((np.array(imp.impulse[:2]), dP - np.array([f.x * dt, (f.z - Mg) * dt])))
        # q1 against the ground: encoder (paper q1 = -ankle of the stance leg) + the stance foot's pitch
        s = S[k]
        leg = slice(3, 6) if s.stance == 0 else slice(6, 9)
        enc = -x0[5] if s.stance == 0 else -x0[8]
        pitch = x0[2] + np.sum(x0[leg])
        assert abs(s.q[0] - (enc + pitch)) < 1e-12
    res = np.abs(np.array(res))
    assert np.max(res) < 0.02 and np.median(res) < 1e-3, np.max(res)
    # every impact whose period has both ends in the bag (the run stops at the last impact: its end state is
    # the final one, without /joint_states)
    assert len(jumps) == sum(1 for t in impact if t <= bp.ns(S[-2].stamp)) >= STEPS - 1
    for J, jump in jumps:
        assert np.max(np.abs(J - jump)) < 0.02 and J[1] > 1.0, (J, jump)   # a landing: N s upward
    # negative control: the impacts left out, the periods they end do not balance
    worst = max(np.max(np.abs(jump - 0.0)) for _, jump in jumps)
    assert worst > 1.0
