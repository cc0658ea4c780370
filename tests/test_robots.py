"""Robots as directories (biped_model.robot, scripts/robot, --robot): the stamp and its refusal, each bad
description case (one line naming the field or the file, exit status 2, nothing written), the derived gait
settings (the default robot's values unchanged), --robot reaching a pool's worker process and the provenance
record, the default robot unchanged; the round trip (new, build a reduced family, check, walk) is marked slow.

Most robots here are copies of the default robot with one field changed whose family is the default robot's
family stamped for the copy (``robot_dir``): a fixture shortcut for the plumbing tests (the family is not
rebuilt; a torque limit raised above the one the family was built for leaves every step of it feasible).
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from biped_model.description import DescriptionError, load_description, parse_description, standing_torques
from biped_model.robot import (FAMILY_FILE, STAMP_FILE, STAMP_KEY, RobotError, description_hash, file_sha256,
                               resolve_robot)
from biped_model.settings import DEFAULT_ROBOT, default_robot_dir

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
B7 = default_robot_dir()


def _set(tree: dict, dotted: str, value) -> dict:
    node = tree
    *head, last = dotted.split(".")
    for k in head:
        node = node[k]
    node[last]["value"] = value
    return tree


def robot_dir(tmp: Path, name: str, edits: dict | None = None, family: bool = True, stamp_for: str | None = None) -> Path:
    """A robot directory under ``tmp``: biped7's description with ``edits`` (dotted field -> value), its
    gait.yaml, and (``family``) biped7's family stamped for the new description (or for ``stamp_for``'s hash)."""
    d = tmp / name
    d.mkdir(parents=True)
    tree = yaml.safe_load((B7 / "description.yaml").read_text())
    for k, v in (edits or {}).items():
        _set(tree, k, v)
    (d / "description.yaml").write_text(yaml.safe_dump(tree, sort_keys=False))
    shutil.copyfile(B7 / "gait.yaml", d / "gait.yaml")
    if family:
        data = json.loads((B7 / FAMILY_FILE).read_text())
        h = stamp_for if stamp_for is not None else description_hash(parse_description(tree))
        data[STAMP_KEY] = {"description_sha256": h, "description": "description.yaml"}
        (d / FAMILY_FILE).write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    return d


def robot_cli(*args, cwd=ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([PY, "-m", "biped_controller.studies.robots", *args], cwd=cwd, capture_output=True,
                          text=True)


@pytest.fixture(autouse=True)
def _default_robot_after():
    """Every test leaves this process's selected robot the default one (trial.context.select_robot)."""
    yield
    from biped_controller.studies.trial.context import select_robot
    select_robot("")


def _files(d: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted(d.iterdir())} if d.exists() else {}


# ------------------------------------------------------------------------------------------ the default robot
def test_default_robot_is_biped7_and_its_family_bit_for_bit_stamped():
    r = resolve_robot(None)
    assert r.name == DEFAULT_ROBOT and r.is_default and r.directory == B7.resolve()
    # the committed family is untouched: its stamp lives beside it and names its bytes
    side = json.loads((B7 / STAMP_FILE).read_text())
    assert side["family_sha256"] == file_sha256(B7 / FAMILY_FILE)
    assert STAMP_KEY not in json.loads((B7 / FAMILY_FILE).read_text())
    assert r.check_stamp() == description_hash(load_description()) == side["description_sha256"]
    assert resolve_robot("biped7") == r == resolve_robot(str(B7))


def test_sidecar_stamp_binds_one_family_file(tmp_path):
    """biped7's sidecar stamp copied beside another family file (other bytes) stamps nothing: refused."""
    d = tmp_path / "b"
    shutil.copytree(B7, d)
    assert resolve_robot(str(d)).check_stamp()
    data = json.loads((d / FAMILY_FILE).read_text())
    data["description"] += " "
    (d / FAMILY_FILE).write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    with pytest.raises(RobotError, match="has no stamp"):
        resolve_robot(str(d)).family()


# ------------------------------------------------------------------------------------------ the stamp
def test_family_for_another_description_is_refused_naming_both_files(tmp_path):
    other = robot_dir(tmp_path, "heavy", {"torso.mass": 25.0}, stamp_for=description_hash(load_description()))
    r = resolve_robot(str(other))
    with pytest.raises(RobotError) as exc:
        r.family()
    msg = str(exc.value)
    assert "\n" not in msg and str(r.family_path) in msg and str(r.description_path) in msg
    assert "another description" in msg
    # the CLI: one line, exit 2
    for cmd in (["check", str(other)], ):
        p = robot_cli(*cmd)
        assert p.returncode == 2 and p.stderr.count("\n") == 1 and "another description" in p.stderr, p.stderr


def test_matching_stamp_is_accepted(tmp_path):
    ok = robot_dir(tmp_path, "strong", {"torque_limits.hip": 160.0})
    r = resolve_robot(str(ok))
    assert r.family().p_d == 0.463
    assert r.description_hash() != resolve_robot(None).description_hash()


def test_description_edit_invalidates_the_stamp(tmp_path):
    d = robot_dir(tmp_path, "edited", {"torque_limits.hip": 160.0})
    resolve_robot(str(d)).check_stamp()
    tree = yaml.safe_load((d / "description.yaml").read_text())
    (d / "description.yaml").write_text(yaml.safe_dump(_set(tree, "foot.mass", 0.6), sort_keys=False))
    with pytest.raises(RobotError, match="another description"):
        resolve_robot(str(d)).check_stamp()


def test_reason_text_does_not_change_the_hash():
    tree = yaml.safe_load((B7 / "description.yaml").read_text())
    tree["torso"]["mass"]["reason"] = "another reason"
    assert description_hash(parse_description(tree)) == description_hash(load_description())


# ------------------------------------------------------------------------------------------ bad input
BAD = [
    ({"torso.mass": -1.0}, "torso.mass"),
    ({"thigh.mass": 0.0}, "thigh.mass"),
    ({"shin.length": 0.0}, "shin.length"),
    ({"thigh.length": -0.4}, "thigh.length"),
    ({"foot.length": -0.2}, "foot.length"),
    ({"torque_limits.knee": 20.0}, "torque_limits.knee"),
]


@pytest.mark.parametrize("edits,field", BAD, ids=[f for _, f in BAD])
def test_bad_description_is_one_line_naming_the_field_exit_2_nothing_written(tmp_path, edits, field):
    d = robot_dir(tmp_path, "bad", edits, family=False)
    before = _files(d)
    for cmd in (["build", str(d)], ["check", str(d)]):
        p = robot_cli(*cmd)
        assert p.returncode == 2, p.stdout + p.stderr
        assert p.stderr.count("\n") == 1 and field in p.stderr and "description.yaml" in p.stderr, p.stderr
    assert _files(d) == before
    # new --set with the bad value: nothing created
    target = tmp_path / "never"
    k, v = next(iter(edits.items()))
    p = robot_cli("new", str(target), "--from", "biped7", "--set", f"{k}={v}")
    assert p.returncode == 2 and field in p.stderr and p.stderr.count("\n") == 1, p.stderr
    assert not target.exists()


def test_missing_and_unknown_fields(tmp_path):
    tree = yaml.safe_load((B7 / "description.yaml").read_text())
    del tree["foot"]["mass"]
    with pytest.raises(DescriptionError, match=r"'foot\.mass'"):
        parse_description(tree)
    tree = yaml.safe_load((B7 / "description.yaml").read_text())
    tree["foot"]["width"] = {"value": 0.1, "reason": "x"}
    with pytest.raises(DescriptionError, match=r"unknown field 'foot\.width'"):
        parse_description(tree)
    tree = yaml.safe_load((B7 / "description.yaml").read_text())
    tree["arms"] = {"value": 2, "reason": "x"}
    with pytest.raises(DescriptionError, match=r"unknown field 'arms'"):
        parse_description(tree)
    p = robot_cli("new", str(tmp_path / "x"), "--from", "biped7", "--set", "foot.width=0.1")
    assert p.returncode == 2 and "foot.width" in p.stderr and not (tmp_path / "x").exists()


def test_standing_torque_threshold():
    """The knee must hold single support with the hip 0.925 leg lengths over the ankle: 49.9 N m for biped7
    (worked by hand: knee 0.152 m ahead of the hip line, 36.5 kg above it plus the thigh's 6 kg at half
    that arm); a limit just below is refused, just above accepted."""
    d = load_description()
    ankle, knee, hip = standing_torques(d)
    zk = (0.74 ** 2 + 0.4 ** 2 - 0.4 ** 2) / (2 * 0.74)
    xk = (0.4 ** 2 - zk ** 2) ** 0.5
    assert knee == pytest.approx(9.81 * ((20.0 + 10.5) * xk + 6.0 * xk / 2), rel=1e-12)
    assert hip == 0.0 and 0 < ankle < knee
    tree = yaml.safe_load((B7 / "description.yaml").read_text())
    parse_description(_set(tree, "torque_limits.knee", knee * 1.001))
    with pytest.raises(DescriptionError, match="torque_limits.knee.*cannot hold the robot standing"):
        parse_description(_set(tree, "torque_limits.knee", knee * 0.999))


def test_robot_without_family_is_refused(tmp_path):
    d = robot_dir(tmp_path, "unbuilt", {"torque_limits.hip": 160.0}, family=False)
    p = robot_cli("check", str(d))
    assert p.returncode == 2 and p.stderr.count("\n") == 1 and FAMILY_FILE in p.stderr, p.stderr
    p = subprocess.run([PY, "-m", "biped_controller.studies.experiment", "walk", "--steps", "1", "--robot", str(d)],
                       cwd=ROOT, capture_output=True, text=True)
    assert p.returncode == 2 and p.stderr.count("\n") == 1 and FAMILY_FILE in p.stderr, p.stderr
    p = robot_cli("check", "no_such_robot")
    assert p.returncode == 2 and "no_such_robot" in p.stderr


# ------------------------------------------------------------------------------------------ scripts/robot
def test_new_copies_and_derives_with_reasons_biped7_values_unchanged(tmp_path):
    p = robot_cli("new", str(tmp_path / "same"), "--from", "biped7")
    assert p.returncode == 0, p.stderr
    g7 = yaml.safe_load((B7 / "gait.yaml").read_text())
    g = yaml.safe_load((tmp_path / "same" / "gait.yaml").read_text())
    for k in ("step_duration", "preferred_stride", "strides", "smoothing_breakpoints", "zmp_margin"):
        assert g[k]["value"] == g7[k]["value"], k
        assert g[k]["reason"].startswith("derived")
    assert g["initial_hip_height"]["value"] == 0.74
    assert (tmp_path / "same" / "description.yaml").read_bytes() == (B7 / "description.yaml").read_bytes()
    p = robot_cli("new", str(tmp_path / "same"), "--from", "biped7")
    assert p.returncode == 2 and "exists" in p.stderr


def test_new_scales_with_leg_length_and_foot(tmp_path):
    """Legs 1.5x longer: strides and hip height x 1.5, step time x sqrt(1.5) (same Froude number); a 0.1 m
    foot: the ZMP margin halves (the same 20 % of the half-foot)."""
    p = robot_cli("new", str(tmp_path / "big"), "--from", "biped7", "--set", "thigh.length=0.6",
                  "--set", "shin.length=0.6", "--set", "thigh.com_from_proximal=0.3", "--set", "shin.com_from_proximal=0.3",
                  "--set", "foot.length=0.1", "--set", "foot.l_min=-0.05", "--set", "foot.l_max=0.05")
    assert p.returncode == 0, p.stderr
    g = yaml.safe_load((tmp_path / "big" / "gait.yaml").read_text())
    assert g["preferred_stride"]["value"] == pytest.approx(0.463 * 1.5)
    assert g["step_duration"]["value"] == pytest.approx(0.463 * 1.5 ** 0.5, abs=1e-6)
    assert g["strides"]["value"][0] == pytest.approx(0.45) and g["strides"]["value"][-1] == pytest.approx(0.975)
    assert g["preferred_stride"]["value"] in g["strides"]["value"]
    assert g["preferred_stride"]["value"] in g["smoothing_breakpoints"]["value"]
    assert g["zmp_margin"]["value"] == pytest.approx(0.01)
    assert g["initial_hip_height"]["value"] == pytest.approx(1.11)
    froude = lambda gy: (gy["preferred_stride"]["value"] / gy["step_duration"]["value"]) ** 2  # noqa: E731
    assert froude(g) / 1.2 == pytest.approx(froude(yaml.safe_load((B7 / "gait.yaml").read_text())) / 0.8, rel=1e-5)
    d = load_description(tmp_path / "big" / "description.yaml")
    assert d.leg_length == pytest.approx(1.2) and "set by scripts/robot new" in (tmp_path / "big" / "description.yaml").read_text()


def test_list_names_the_default_robot():
    p = robot_cli("list")
    assert p.returncode == 0
    line = next(x for x in p.stdout.splitlines() if x.startswith("biped7"))
    assert line.split()[1:4] == ["41", "0.8", "0.2"] and "built [0.35, 0.65] m" in line


def test_interrupted_build_leaves_the_previous_family(tmp_path, monkeypatch):
    """A build interrupted inside the two-process build (after part of the family file was written) leaves the
    previous family byte for byte and no temporary file."""
    from biped_controller.gaits import build
    from biped_controller.studies import robots
    d = robot_dir(tmp_path, "strong", {"torque_limits.hip": 160.0})
    before = _files(d)

    def interrupted(st, **kw):
        (d / f".{FAMILY_FILE}.{__import__('os').getpid()}.tmp").write_text('{"family": ')   # cmd_build's temporary
        raise KeyboardInterrupt
    monkeypatch.setattr(build, "build_family", interrupted)
    with pytest.raises(KeyboardInterrupt):
        robots.cmd_build(str(d), force=False, speed_sweep=False, warm_from="biped7")
    assert _files(d) == before
    resolve_robot(str(d)).family()


# ------------------------------------------------------------------------------------------ --robot plumbing
def test_robot_reaches_a_pool_worker(tmp_path):
    """The parent selects the default robot; a spawned worker given settings for another robot runs on it
    (its mass and hash), since the robot travels in the settings, not in a global of the parent."""
    from biped_controller.closed_loop.executor import PoolExecutor
    from biped_controller.studies.trial.context import robot_in_process, select_robot, selected_robot
    from biped_controller.studies.trial.settings import parse_overrides
    d = robot_dir(tmp_path, "heavy", {"torso.mass": 25.0, "torque_limits.knee": 200.0})
    st = parse_overrides((), robot=str(d))
    select_robot("")
    assert selected_robot() == ""
    with PoolExecutor(1) as ex:
        (got,) = ex.map(robot_in_process, [(st,)])
    assert got["pid"] != __import__("os").getpid()
    assert got["directory"] == str(d.resolve()) and got["mass"] == pytest.approx(46.0)
    assert got["robot_hash"] == resolve_robot(str(d)).description_hash()
    assert selected_robot() == ""            # the parent's selection untouched
    assert robot_in_process(parse_overrides(()))["robot"] == "biped7"


def test_trial_tasks_select_the_robot_of_their_settings(tmp_path):
    """The pool's task functions activate their settings' robot before anything else (a task run in this
    process after the default robot was selected ends with the robot of its settings selected)."""
    from biped_controller.studies.trial import search
    from biped_controller.studies.trial.context import select_robot, selected_robot
    from biped_controller.studies.trial.runs import paper_push
    from biped_controller.studies.trial.settings import parse_overrides
    d = robot_dir(tmp_path, "strong", {"torque_limits.hip": 160.0})
    st = parse_overrides((), robot=str(d))
    select_robot("")
    rec = search._trial((paper_push(10.0), "none", st))
    assert selected_robot() == str(d.resolve()) and rec["force"] == 10.0
    select_robot("")
    from biped_controller.studies.capmap.spec import Cell, SimSpec
    from biped_controller.studies.capmap.task import simulate
    rec = simulate(SimSpec(Cell("none", "forward", 0.5, 0.025), 10.0), st)
    assert selected_robot() == str(d.resolve()) and rec["force"] == 10.0
    select_robot("")


def test_default_robot_settings_equal_the_settings_before_robots():
    from biped_controller.studies.trial.settings import RunSettings, parse_overrides
    assert parse_overrides(()) == RunSettings()
    assert parse_overrides((), robot="biped7") == RunSettings() == parse_overrides((), robot=str(B7))
    assert "robot" not in RunSettings().describe()


def test_provenance_names_the_robot_and_its_hash(tmp_path):
    from biped_controller.studies import provenance
    d = robot_dir(tmp_path, "strong", {"torque_limits.hip": 160.0})
    out = tmp_path / "out"
    out.mkdir()
    f = out / "a.json"
    run = provenance.track(out, args=argparse.Namespace(robot=str(d), profile="default"), argv=["x"])
    f.write_text("{}")
    rec = run.finish()[f]
    assert rec["robot"] == str(d.resolve()) and rec["robot_hash"] == resolve_robot(str(d)).description_hash()
    g = out / "b.json"
    run = provenance.track(out, args=argparse.Namespace(profile="default"), argv=["y"])
    g.write_text("{}")
    rec = run.finish()[g]
    assert rec["robot"] == "biped7" and rec["robot_hash"] == description_hash(load_description())
    assert set(provenance.ROBOT_FIELDS) <= set(rec) and not set(provenance.ROBOT_FIELDS) & set(provenance.FIELDS)
    # a record written before robots (no robot fields) is complete
    assert provenance.missing_fields({k: None for k in provenance.FIELDS}) == []


def test_experiment_walk_on_another_robot_records_it(tmp_path):
    d = robot_dir(tmp_path, "strong", {"torque_limits.hip": 160.0})
    out = tmp_path / "walk.json"
    p = subprocess.run([PY, "-m", "biped_controller.studies.experiment", "walk", "--steps", "2", "--robot", str(d),
                        "--json", str(out)], cwd=ROOT, capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    rec = json.loads((tmp_path / "provenance.json").read_text())["walk.json"]
    assert rec["robot"] == str(d.resolve()) and rec["robot_hash"] == resolve_robot(str(d)).description_hash()
    assert json.loads(out.read_text())["settings"]["robot"] == str(d.resolve())
    assert f"robot {d.resolve()}" in p.stdout


def test_node_robot_parameter_resolves_the_robot_files(tmp_path):
    from biped_sim.graph.checks import RobotFilesError, load_robot_files
    d = robot_dir(tmp_path, "heavy", {"torso.mass": 25.0, "torque_limits.knee": 200.0})
    desc, fam = load_robot_files("", "", str(d))
    assert desc.total_mass == pytest.approx(46.0) and fam.p_d == 0.463
    bad = robot_dir(tmp_path, "stale", {"torso.mass": 25.0, "torque_limits.knee": 200.0},
                    stamp_for=description_hash(load_description()))
    with pytest.raises(RobotFilesError) as exc:
        load_robot_files("", "", str(bad))
    assert exc.value.field == "robot" and "another description" in str(exc.value)
    d7, _ = load_robot_files("", "", "")
    assert d7 == load_description()


# ------------------------------------------------------------------------------------------ the round trip
@pytest.mark.slow
def test_round_trip_new_build_check_walk(tmp_path):
    """new from biped7 with a heavier foot, build a reduced family (5 strides, one smoothing pass, no speed
    sweep; the preferred stride warm-started from biped7's), check it, walk 3 steps on the rigid plant."""
    d = tmp_path / "footy"
    assert robot_cli("new", str(d), "--from", "biped7", "--set", "foot.mass=0.55").returncode == 0
    g = yaml.safe_load((d / "gait.yaml").read_text())
    g["strides"]["value"] = [0.4375, 0.45, 0.463, 0.475, 0.4875]
    g["smoothing_breakpoints"]["value"] = [0.4375, 0.45, 0.463, 0.475, 0.4875]
    g["smoothing_weights"]["value"] = [1.0e4]
    g["max_iterations"]["value"] = 200
    (d / "gait.yaml").write_text(yaml.safe_dump(g, sort_keys=False))
    p = robot_cli("build", str(d), "--warm-from", "biped7", "--no-speed-sweep", "--force")
    assert (d / FAMILY_FILE).is_file(), p.stdout + p.stderr
    data = json.loads((d / FAMILY_FILE).read_text())
    assert data[STAMP_KEY]["description_sha256"] == resolve_robot(str(d)).description_hash()
    p = robot_cli("check", str(d))
    assert p.returncode in (0, 1) and "stamp" in p.stdout and "matches" in p.stdout, p.stdout + p.stderr
    from biped_controller.studies.trial.runs import run
    from biped_controller.studies.trial.settings import parse_overrides
    res = run(3, "both", settings=parse_overrides((), robot=str(d)))
    assert res.steps_walked == 3 and not res.fallen


def test_new_derives_the_size_dependent_run_settings(tmp_path):
    """settings.yaml: a copy of biped7 gets the configuration files' values bit for bit; a 30 kg torso on
    1.2 m legs the touch threshold x weight ratio, the fall height x 1.5, tau_dot_max x sqrt(1.5); they reach
    the run's settings (and a --set still wins)."""
    from biped_sim.plant.config import load_sim_config
    from biped_controller.core.control.config import load_controller_config
    from biped_controller.studies.trial.settings import parse_overrides
    assert robot_cli("new", str(tmp_path / "same"), "--from", "biped7").returncode == 0
    own = yaml.safe_load((tmp_path / "same" / "settings.yaml").read_text())
    sim, ctrl = load_sim_config(), load_controller_config()
    assert own["push_height"]["value"] == sim.push_height == 0.3125
    assert own["observer_height"]["value"] == ctrl.observer_height == 0.3125
    assert own["mujoco_fall_hip_height"]["value"] == sim.mujoco_fall_hip_height == 0.5
    assert own["mujoco_touch_threshold"]["value"] == sim.mujoco_touch_threshold == 20.0
    assert own["tau_dot_max"]["value"] == ctrl.tau_dot_max == 46.3
    assert all(v["reason"].startswith("derived") for v in own.values())
    p = robot_cli("new", str(tmp_path / "big"), "--from", "biped7", "--set", "thigh.length=0.6", "--set", "shin.length=0.6",
                  "--set", "thigh.com_from_proximal=0.3", "--set", "shin.com_from_proximal=0.3", "--set", "torso.mass=30")
    assert p.returncode == 0, p.stderr
    own = yaml.safe_load((tmp_path / "big" / "settings.yaml").read_text())
    assert own["mujoco_fall_hip_height"]["value"] == pytest.approx(0.75)
    assert own["mujoco_touch_threshold"]["value"] == pytest.approx(20.0 * 51.0 / 41.0, abs=1e-6)
    assert own["tau_dot_max"]["value"] == pytest.approx(46.3 * 1.5 ** 0.5, abs=1e-4)
    # applied: a robot with settings.yaml and a (fixture) family
    d = robot_dir(tmp_path, "tall_torso", {"torso.com_from_proximal": 0.4, "torque_limits.knee": 200.0})
    (d / "settings.yaml").write_text(yaml.safe_dump({"push_height": {"value": 0.4, "reason": "torso com"},
                                                     "observer_height": {"value": 0.4, "reason": "torso com"}}))
    st = parse_overrides((), robot=str(d))
    assert st.sim_config().push_height == 0.4 and st.ctrl_config("both").observer_height == 0.4
    assert parse_overrides(("push_height=0.3",), robot=str(d)).sim_config().push_height == 0.3
    (d / "settings.yaml").write_text(yaml.safe_dump({"push_height": {"value": 0.4, "reason": ""}}))
    with pytest.raises(RobotError, match="push_height"):
        parse_overrides((), robot=str(d))


@pytest.mark.ros
@pytest.mark.slow
def test_launch_on_another_robot_publishes_its_urdf(ros_domain, tmp_path):
    """scripts/launch --robot: the nodes take the robot (parameter robot); the bag's /robot_description is
    that robot's URDF (its 0.55 kg feet), the walk reaches its steps; a robot with a stale family: exit 2."""
    from biped_model.description import make_urdf
    from biped_sim.recording.bag_reader import read_bag
    d = robot_dir(tmp_path, "strong_feet", {"foot.mass": 0.55, "torque_limits.hip": 160.0})
    bag = tmp_path / "bag"
    p = subprocess.run([PY, "-m", "biped_sim.graph.launch", "--steps", "2", "--robot", str(d), "--bag", str(bag)],
                       cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    data = read_bag(bag, decode=True)
    (urdf,) = [m.data for t, _, _, m in data["messages"] if t == "/robot_description"]
    assert urdf == make_urdf(resolve_robot(str(d)).description()) != make_urdf(load_description())
    assert data["counts"]["/sim/impacts"] == 2
    stale = robot_dir(tmp_path, "stale", {"foot.mass": 0.55}, stamp_for=description_hash(load_description()))
    p = subprocess.run([PY, "-m", "biped_sim.graph.launch", "--steps", "2", "--robot", str(stale),
                        "--bag", str(tmp_path / "bag2")], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert p.returncode == 2 and "another description" in p.stderr and not (tmp_path / "bag2").exists()


def test_initial_guess_takes_the_hip_height_of_the_gait_settings():
    """gait.yaml's initial_hip_height sets the initial guess's double-support posture; without it 0.74 m
    (the default robot's guess, unchanged)."""
    import dataclasses
    import numpy as np
    from biped_controller.gaits.optimizer import StepOptimizer, basis, double_support_posture, load_gait_settings
    st = load_gait_settings()
    assert "initial_hip_height" not in st.raw
    base = StepOptimizer(settings=st)
    c = base.initial_guess(0.463)
    phi, _, _ = basis(np.array([1.0]), st.T)
    raw = dict(st.raw, initial_hip_height={"value": 0.74, "reason": "same"})
    same = StepOptimizer(settings=dataclasses.replace(st, raw=raw)).initial_guess(0.463)
    assert np.array_equal(c, same)
    raw = dict(st.raw, initial_hip_height={"value": 0.70, "reason": "lower"})
    low = StepOptimizer(settings=dataclasses.replace(st, raw=raw)).initial_guess(0.463)
    assert not np.allclose(c, low)
    # the end of the guessed step is (to the least-squares projection) the 0.70 m posture
    qT = double_support_posture(base.desc, 0.463, hip_height=0.70)
    assert np.max(np.abs((phi @ low.T)[0] - qT)) < 0.1 < np.max(np.abs((phi @ c.T)[0] - qT))


def test_force_search_ranges_scale_with_the_robot(tmp_path, monkeypatch):
    """M sqrt(g L) relative to biped7: 1.0 exactly for biped7 (its ranges bit for bit), 46/41 for a 5 kg
    heavier torso on the same legs; robustness's searches follow the robot."""
    from biped_controller.studies import robustness
    from biped_controller.studies.trial.context import force_scale, scaled_force
    assert force_scale("") == 1.0 and scaled_force(2000.0, "") == 2000.0 and scaled_force(5.0, "biped7") == 5.0
    d = robot_dir(tmp_path, "heavy", {"torso.mass": 25.0, "torque_limits.knee": 200.0})
    assert force_scale(str(d)) == pytest.approx(46.0 / 41.0, rel=1e-12)
    assert scaled_force(2000.0, str(d)) == round(2000.0 * 46.0 / 41.0, 3)
    assert robustness.search_for("both") is robustness.SEARCHES["both"]
    monkeypatch.setattr(robustness, "ROBOT", str(d))
    s = robustness.search_for("both")
    assert (s.coarse, s.fmax, s.resolution) == tuple(round(x * 46.0 / 41.0, 3) for x in (40.0, 960.0, 20.0))


def test_no_gait_is_one_line_naming_the_binding_constraint(tmp_path, monkeypatch, capsys):
    """When the preferred stride has no feasible step, build stops there: one line naming the constraint with
    the smallest margin, exit 1, the previous family untouched (the solver's answer is replaced by a failed
    one here: a real infeasible robot costs minutes of SLSQP)."""
    from types import SimpleNamespace
    from biped_controller.gaits import build, generation
    from biped_controller.studies import robots
    d = robot_dir(tmp_path, "strong", {"torque_limits.hip": 160.0})
    before = _files(d)

    class Failing:
        def __init__(self, desc=None, settings=None):
            self.st = settings

        def solve(self, p, c0=None):
            return SimpleNamespace(success=False, criterion=float("nan"), min_margin=-0.0123, min_margin_name="zmp_toe",
                                   message="Positive directional derivative for linesearch", c=None)
    monkeypatch.setattr(robots, "StepOptimizer", Failing)
    monkeypatch.setattr(generation, "generate", lambda *a, **k: pytest.fail("the generator must not run"))
    monkeypatch.setattr(build, "build_family", lambda *a, **k: pytest.fail("the build must not run"))
    assert robots.cmd_build(str(d), force=False, speed_sweep=False) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no feasible gait" in err and "zmp_toe" in err and "-0.0123" in err
    assert _files(d) == before


def test_new_takes_a_given_speed(tmp_path):
    """--speed: the step time is the preferred stride over it (tau_dot_max follows the step time); a speed
    <= 0 is one line, exit 2, nothing created."""
    p = robot_cli("new", str(tmp_path / "slow"), "--from", "biped7", "--speed", "0.8")
    assert p.returncode == 0, p.stderr
    g = yaml.safe_load((tmp_path / "slow" / "gait.yaml").read_text())
    own = yaml.safe_load((tmp_path / "slow" / "settings.yaml").read_text())
    assert g["step_duration"]["value"] == round(0.463 / 0.8, 6) and g["step_duration"]["reason"].startswith("given")
    assert g["preferred_stride"]["value"] == 0.463
    assert own["tau_dot_max"]["value"] == pytest.approx(46.3 / 0.8, abs=1e-4)
    p = robot_cli("new", str(tmp_path / "never"), "--from", "biped7", "--speed", "-1")
    assert p.returncode == 2 and "--speed" in p.stderr and p.stderr.count("\n") == 1
    assert not (tmp_path / "never").exists()


def test_bad_gait_settings_are_one_line_naming_the_file(tmp_path):
    d = tmp_path / "g"
    assert robot_cli("new", str(d), "--from", "biped7").returncode == 0
    g = yaml.safe_load((d / "gait.yaml").read_text())
    g["preferred_stride"]["value"] = 0.47
    (d / "gait.yaml").write_text(yaml.safe_dump(g, sort_keys=False))
    before = _files(d)
    p = robot_cli("build", str(d))
    assert p.returncode == 2 and p.stderr.count("\n") == 1, p.stderr
    assert str(d / "gait.yaml") in p.stderr and "preferred_stride" in p.stderr and "biped7" not in p.stderr
    assert _files(d) == before


# ------------------------------------------------------------------------------------------ build: two processes
def _reduced_robot(tmp: Path, name: str) -> Path:
    """biped7's description and a reduced gait.yaml (4 strides around p_d, one smoothing pass, 150 iterations)."""
    d = robot_dir(tmp, name, family=False)
    g = yaml.safe_load((d / "gait.yaml").read_text())
    g["strides"]["value"] = [0.45, 0.463, 0.475, 0.4875]
    g["smoothing_breakpoints"]["value"] = [0.45, 0.463, 0.475, 0.4875]
    g["smoothing_weights"]["value"] = [1.0e4]
    g["max_iterations"]["value"] = 150
    (d / "gait.yaml").write_text(yaml.safe_dump(g, sort_keys=False))
    return d


@pytest.mark.slow
def test_build_is_the_two_process_build_bit_identical_across_workers(tmp_path):
    """scripts/robot build goes through biped_controller.gaits.build: the family file is the same bit for bit
    with one worker and with two, carries generation.generate's stamp (the description's hash) and passes
    scripts/robot check's stamp test; the build's log names the two-process build."""
    files, outs = [], []
    for workers in (1, 2):
        d = _reduced_robot(tmp_path, f"w{workers}")
        p = robot_cli("build", str(d), "--warm-from", "biped7", "--no-speed-sweep", "--force", "--workers", str(workers))
        assert (d / FAMILY_FILE).is_file(), p.stdout + p.stderr
        assert f"biped_controller.gaits.build, {workers} worker(s)" in p.stdout
        files.append((d / FAMILY_FILE).read_bytes())
        outs.append(d)
    assert files[0] == files[1]
    data = json.loads(files[0])
    assert data[STAMP_KEY]["description_sha256"] == resolve_robot(str(outs[0])).description_hash()
    assert "biped_controller.gaits.build" in data["solver"]["build"]
    assert not list(outs[0].glob(".*.tmp"))
    p = robot_cli("check", str(outs[1]))
    assert "matches" in p.stdout and p.returncode in (0, 1), p.stdout + p.stderr


def test_build_rejects_zero_workers(tmp_path):
    d = robot_dir(tmp_path, "w0")
    before = _files(d)
    p = robot_cli("build", str(d), "--workers", "0")
    assert p.returncode == 2 and p.stderr.count("\n") == 1 and "--workers" in p.stderr
    assert _files(d) == before


# ------------------------------------------------------------------------------------------ the shipped robots
#: robots shipped beside biped7 (docs/robots_compared.md), each with its built family committed
SHIPPED = ("biped7_foot10", "biped7_foot05", "human70", "rabbit")


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_robot_loads_and_its_family_passes_check(name):
    """The committed family (no rebuild) is stamped for the committed description and passes scripts/robot
    check (fit, periodicity, margins, clearance); the description loads and is not biped7's."""
    from biped_controller.studies import robots
    r = resolve_robot(name)
    d = r.description()
    assert d.total_mass > 0 and d.leg_length > 0
    assert r.description_hash() != resolve_robot("biped7").description_hash()
    assert r.check_stamp() == r.description_hash()
    assert robots.cmd_check(name) == 0


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_robot_walks_10_steps_unpushed_rigid(name):
    """10 steps unpushed (mode both, the control period's held torques, rigid plant): no fall (0.3-1.5 s each
    at load 12; the integration-rate walks are committed results, results/robots/NAME_walk_*.json)."""
    from biped_controller.studies.trial.runs import run
    from biped_controller.studies.trial.settings import parse_overrides
    res = run(10, "both", settings=parse_overrides((), robot=name))
    assert res.steps_walked == 10 and not res.fallen


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_robot_walks_10_steps_unpushed_mujoco(name):
    """The same on the MuJoCo plant (0.5-0.8 s each at load 12; its impact times are those of the committed
    ZOH walk in results/robots/NAME_walk_mujoco.json)."""
    from biped_controller.studies.trial.runs import run
    from biped_controller.studies.trial.settings import parse_overrides
    res = run(10, "both", settings=parse_overrides(("plant=mujoco",), robot=name))
    assert res.steps_walked == 10 and not res.fallen


def test_compare_gives_the_dimensionless_impulse(tmp_path):
    """scripts/robot compare: each table's robot and plant from its argv, the boundary F and F dt / (M sqrt(g L))."""
    import math
    out = tmp_path / "cmp.json"
    p = robot_cli("compare", "results/paper_table/rigid_default.json", "results/paper_table/mujoco_default.json",
                  "--json", str(out))
    assert p.returncode == 0, p.stderr
    data = json.loads(out.read_text())
    rigid = data["rows"][data["by"]["biped7/rigid"]]
    table = json.loads((ROOT / "results/paper_table/rigid_default.json").read_text())
    F = table["modes"]["both"]["max_force"]
    assert rigid["modes"]["both"]["max_force"] == F
    assert rigid["modes"]["both"]["impulse"] == pytest.approx(F * 0.025 / (41.0 * math.sqrt(9.81 * 0.8)))
    assert data["rows"][data["by"]["biped7/mujoco"]]["plant"] == "mujoco"
    p = robot_cli("compare", str(tmp_path / "none.json"))
    assert p.returncode == 2 and "none.json" in p.stderr and p.stderr.count("\n") == 1


def test_compare_merges_tables_of_one_robot_and_plant(tmp_path):
    """A second table of the same robot and plant (e.g. dcm_wbc run apart from the paper's modes) adds its modes
    to the same row, each naming its table; a mode in both must agree, else a UsageError naming both files (the
    CLI's one line and exit status 2 for a UsageError: test_compare_gives_the_dimensionless_impulse)."""
    def table(name: str, modes: dict, argv: list[str] | None = None) -> Path:
        p = tmp_path / name
        p.write_text(json.dumps({"argv": argv or ["table"], "modes": {m: {"max_force": f} for m, f in modes.items()}}))
        return p
    a = table("a.json", {"none": 40.0, "both": 500.0})
    b = table("b.json", {"none": 40.0, "dcm_wbc": 520.0})
    c = table("c.json", {"none": 45.0})
    m = table("m.json", {"dcm_wbc": 800.0}, ["table", "--set", "plant=mujoco"])
    out = tmp_path / "cmp.json"
    from biped_controller.studies import robots
    assert robots.cmd_compare([a, b, m], out) == 0
    data = json.loads(out.read_text())
    assert len(data["rows"]) == 2
    rigid = data["rows"][data["by"]["biped7/rigid"]]
    assert rigid["tables"] == [str(a), str(b)]
    assert {k: (v["max_force"], v["table"]) for k, v in rigid["modes"].items()} == {
        "none": (40.0, str(a)), "both": (500.0, str(a)), "dcm_wbc": (520.0, str(b))}
    assert data["rows"][data["by"]["biped7/mujoco"]]["modes"]["dcm_wbc"]["max_force"] == 800.0
    with pytest.raises(robots.UsageError) as exc:
        robots.cmd_compare([a, c], tmp_path / "bad.json")
    assert "a.json" in str(exc.value) and "c.json" in str(exc.value) and "\n" not in str(exc.value)
    assert not (tmp_path / "bad.json").exists()
