"""The stance foot's per-period figures (``lab.foot_quiet``): the arithmetic on hand-made series, and on
short walks of both plants with the MuJoCo sole as contact points against the box it replaced, and the
20-step walk against the quiet-foot targets with the MuJoCo step against the former one."""
from __future__ import annotations

import json

import numpy as np
import pytest

from biped_sim.plant.config import SimConfigError, load_sim_config
from biped_model.mjcf import foot_geom_names, make_mjcf
from lab import foot_quiet as fq


class _Rec:
    def __init__(self, t, fz, cop, stance=0, pitch=0.0):
        self.t, self.stance, self.cop = t, stance, cop
        self.wrench = np.array([0.0, fz, fz * cop])
        self.x = np.zeros(9)
        self.x[2] = pitch            # torso pitch, the stance leg's joints 0: the foot's pitch is this


def _series(fz, cop, dt=1e-3, impacts=(), pitch=None):
    pitch = pitch if pitch is not None else [0.0] * len(fz)
    return [_Rec(i * dt, f, c, pitch=p) for i, (f, c, p) in enumerate(zip(fz, cop, pitch))]


def test_figures_count_what_they_say():
    """Hand-made periods: the first 10 ms after the start and after a touchdown are left out; a period with
    F_z below 20 N, a CoP within 1 mm of heel or toe or an undefined one (F_z <= 0) is counted; |dF_z| is
    taken only between consecutive periods of one support phase (not across the touchdown)."""
    n = 40
    fz = [300.0] * n
    cop = [0.0] * n
    fz[15], cop[15] = 10.0, 0.05          # unloaded (and its CoP is inside)
    cop[16] = -0.0995                     # 0.5 mm from the heel
    cop[17] = 0.0989                      # 1.1 mm from the toe: inside
    fz[18], cop[18] = 0.0, float("nan")   # no load: at an edge, and unloaded
    fz[24] = 100.0                        # the last counted period before the touchdown at 25 ms
    fz[35] = 900.0                        # the first counted after it: its jump from fz[24] (800 N) is not a change
                                          # between periods; the one to fz[36] (600 N) is
    recs = _series(fz, cop, pitch=[0.0] * 12 + [0.02] + [0.0] * 27)
    s = fq.period_series(recs, impact_times=[0.025], skip=0.010)
    # periods 10..24 (start skipped) and 35..39 (10 ms after the touchdown at 25 ms)
    assert s.t.tolist() == pytest.approx([i * 1e-3 for i in list(range(10, 25)) + list(range(35, 40))])
    f = fq.figures(s, -0.1, 0.1)
    assert f["periods"] == 20
    assert f["unloaded"] == pytest.approx(2 / 20)
    assert f["edge"] == pytest.approx(2 / 20)
    d = [abs(fz[i] - fz[i - 1]) for i in list(range(11, 25)) + list(range(36, 40))]
    assert len(d) == 18 and f["dfz_max"] == 600.0
    assert f["dfz_p99"] == pytest.approx(np.percentile(d, 99))
    assert f["max_pitch"] == pytest.approx(0.02)
    bins = fq.binned(s, -0.1, 0.1, width=0.005)
    assert [b["from"] for b in bins] == [0.01, 0.015, 0.02]
    assert sum(b["periods"] for b in bins) == 20
    assert bins[1]["edge"] == pytest.approx(2 / 5)     # periods 15..19 since the start


def test_sole_points_in_the_mjcf_and_their_bad_values():
    """n contact spheres from heel to toe, named as the plant looks them up; 0 keeps the box; other counts
    are refused naming the key."""
    from biped_sim.plant.mujoco import contact_settings
    from biped_model.description import load_description
    desc = load_description()
    text = make_mjcf(desc, contact_settings(load_sim_config(plant="mujoco", mujoco_sole_points=5)))
    for side in ("left", "right"):
        for name in foot_geom_names(side, 5):
            assert f'name="{name}" type="sphere"' in text
    assert 'type="box"' not in text
    assert 'pos="-0.1 0 0.005"' in text and 'pos="0.1 0 0.005"' in text and 'pos="0.0 0 0.005"' in text
    box = make_mjcf(desc, contact_settings(load_sim_config(plant="mujoco", mujoco_sole_points=0)))
    assert box.count('type="box"') == 2 and 'type="sphere"' not in box
    for bad in (1, -2, 2.5, 500):
        with pytest.raises(SimConfigError, match="mujoco_sole_points"):
            load_sim_config(plant="mujoco", mujoco_sole_points=bad)


@pytest.fixture(scope="module")
def walks():
    return {name: fq.run_figures(plant, "both", 3, overrides)
            for name, plant, overrides in (("rigid", "rigid", ()), ("points", "mujoco", ()),
                                           ("box", "mujoco", ("mujoco_sole_points=0",)))}


def test_rigid_foot_is_quiet(walks):
    o = walks["rigid"]["overall"]
    assert walks["rigid"]["steps_walked"] == 3
    assert o["unloaded"] == 0.0 and o["edge"] == 0.0 and o["dfz_p99"] < 50.0 and o["max_pitch"] < 1e-12


def test_sole_points_quiet_the_mujoco_stance_foot(walks):
    """3-step MuJoCo walk, mode both, default settings (the sole as 5 contact points): no period with the
    stance normal force below 20 N, the CoP at an edge in at most 3 % of the periods, |dF_z| p99 at most
    200 N (measured 0 %, 1.5 %, 144 N). Negative control: the box sole, all else the same, chatters above
    the thresholds (measured 0 %, 13.8 %, 558 N)."""
    p, b = walks["points"], walks["box"]
    assert p["steps_walked"] == 3 and not p["fallen"] and b["steps_walked"] == 3
    po, bo = p["overall"], b["overall"]
    assert po["periods"] > 1200 and bo["periods"] > 1200
    assert po["unloaded"] == 0.0 and po["edge"] <= 0.03 and po["dfz_p99"] <= 200.0
    assert bo["edge"] > 0.10 and bo["dfz_p99"] > 400.0


def test_the_mujoco_step_meets_the_quiet_foot_targets():
    """The targets of the quiet stance foot, undisturbed 20-step walk on MuJoCo, mode both, default settings
    (``mujoco_timestep`` 0.125 ms): no counted period with F_z below 20 N, the CoP within 1 mm of an edge in
    at most 2 % of them, |dF_z| p99 at most 200 N (measured 0 %, 1.7 %, 133 N). Negative control: the same
    walk with the former 0.5 ms step misses both the edge and the |dF_z| targets (measured 0 %, 3.2 %,
    283 N): over a MuJoCo step in which the flat sole carries no force the held ankle torque spins the foot
    in proportion to the step (``config/simulator.yaml``)."""
    assert load_sim_config().mujoco_timestep == pytest.approx(1.25e-4)
    fix = fq.run_figures("mujoco", "both", 20)
    off = fq.run_figures("mujoco", "both", 20, ("mujoco_timestep=0.0005",))
    assert fix["steps_walked"] == 20 and not fix["fallen"] and off["steps_walked"] == 20
    fo, oo = fix["overall"], off["overall"]
    assert fo["periods"] > 9000 and oo["periods"] > 9000
    assert fo["unloaded"] == 0.0 and fo["edge"] <= 0.02 and fo["dfz_p99"] <= 200.0
    assert oo["edge"] > 0.02 and oo["dfz_p99"] > 200.0
    assert oo["edge"] > fo["edge"] and oo["dfz_p99"] > fo["dfz_p99"]


def test_command_line_and_its_json(tmp_path, capsys):
    out = tmp_path / "f.json"
    assert fq.main(["--plant", "rigid", "--steps", "1", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "rigid mode both, 1 steps" in text and "0.225-0.250" in text
    data = json.loads(out.read_text())
    assert data["provenance"]["command"].endswith("--plant rigid --steps 1 --json " + str(out))
    assert len(data["provenance"]["load_average"]) == 3 and data["overall"]["unloaded"] == 0.0
    assert fq.main(["--plant", "rigid", "--steps", "1", "--set", "Kp=-1"]) == 2
    assert "Kp" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        fq.main(["--steps", "0"])
