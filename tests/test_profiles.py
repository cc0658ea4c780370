"""Named profiles (config/profiles/) and the studies' command lines: a profile is its overrides (the same
settings and store fingerprint as the equivalent --set flags), --set and --observer override it, an unknown
name is an error naming the known ones; a bad command-line value is one line naming the option, exit
status 2, no traceback."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from biped_model.profiles import ProfileError, load_profile, profile_names
from biped_controller.studies import capability_map as cmap
from biped_controller.studies.trial import settings as ts

ROOT = Path(__file__).resolve().parents[1]
#: the real-sensor design point of docs/robustness.md as --set flags
REAL_SENSORS = ["momentum_observer=true", "state_estimator=true", "sensor_noise_q=5e-4", "sensor_encoder_bits=14",
                "sensor_noise_qd=5e-2", "sensor_noise_pitch=1e-3", "momentum_observer_gain=50"]


def test_the_named_profiles_are_there():
    assert set(profile_names()) >= {"default", "paper", "real-sensors", "real-sensors-mujoco", "delay2"}


@pytest.mark.parametrize("name", profile_names())
def test_a_profile_lists_only_settings_that_differ_each_with_a_reason(name):
    prof = load_profile(name)
    reasons = dict(prof.reasons)
    diff = ts.differences(ts.parse_overrides((), profile=name))
    assert diff["profile"] == name
    for key, value in prof.settings:
        assert reasons[key], key
        assert key in diff["differs"], f"profile {name}: {key} = {value!r} is the default already"
    for key, _ in prof.perturbation:
        assert reasons[f"perturbation.{key}"], key
        assert key in diff.get("perturbation", {}), f"profile {name}: perturbation {key} is the identity's"


def test_a_profile_is_its_overrides():
    paper = ts.parse_overrides((), profile="paper")
    off = ts.parse_overrides((), "off")
    assert paper.describe() == off.describe()
    assert cmap.fingerprint(cmap.MapSpec(settings=paper)) == cmap.fingerprint(cmap.MapSpec(settings=off))
    assert ts.parse_overrides((), profile="default") == ts.DEFAULT_SETTINGS
    real = ts.parse_overrides((), profile="real-sensors").describe()
    flags = ts.parse_overrides(REAL_SENSORS).describe()
    assert (real["controller"], real["simulator"]) == (flags["controller"], flags["simulator"])
    mj = ts.parse_overrides((), profile="real-sensors-mujoco")
    assert mj.sim_config().plant == "mujoco" and mj.describe()["controller"] == real["controller"]
    d2 = ts.parse_overrides((), profile="delay2")
    assert d2.perturbation.delay == 2 and d2.ctrl_config("both").delay_compensation == 2


def test_set_and_observer_override_a_profile():
    s = ts.parse_overrides(["momentum_observer_gain=100"], profile="real-sensors")
    assert s.ctrl_config("both").momentum_observer_gain == 100 and s.ctrl_config("both").state_estimator
    assert ts.parse_overrides((), "on", profile="paper").ctrl_config("both").disturbance_observer is True
    s = ts.run_settings("delay2", perturb=["delay=1"])
    assert s.perturbation.delay == 1 and s.ctrl_config("both").delay_compensation == 2


def test_differences_name_only_what_differs():
    assert ts.differences(ts.DEFAULT_SETTINGS) == {"profile": "default", "differs": {}}
    d = ts.differences(ts.parse_overrides(["Kp=900"], profile="paper"))
    assert d == {"profile": "paper", "differs": {"Kp": 900, "disturbance_observer": False}}


def test_an_unknown_profile_names_the_known_ones():
    with pytest.raises(ProfileError, match="known profiles: .*paper"):
        load_profile("no_such_profile")
    with pytest.raises(ProfileError, match="no_such_profile"):
        ts.parse_overrides((), profile="no_such_profile")


def test_a_malformed_profile_is_an_error_naming_the_entry(tmp_path):
    d = tmp_path / "profiles"
    d.mkdir()
    (d / "bad.yaml").write_text('description: "x"\nsettings:\n  Kp: 900\n')
    with pytest.raises(ProfileError, match="settings.Kp"):
        load_profile("bad", tmp_path)
    (d / "bad.yaml").write_text('description: "x"\nsettings:\n  Kp: {value: 900, reason: ""}\n')
    with pytest.raises(ProfileError, match="no reason"):
        load_profile("bad", tmp_path)


# ------------------------------------------------------------------------------------------ command lines
def _cli(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *argv], capture_output=True, text=True, cwd=ROOT, timeout=300)


BAD_VALUES = [
    (("biped_controller.studies.experiment", "push", "--force", "nan"), "--force", "nan"),
    (("biped_controller.studies.experiment", "push", "--duration", "-1"), "--duration", "-1"),
    (("biped_controller.studies.experiment", "walk", "--steps", "-3"), "--steps", "-3"),
    (("biped_controller.studies.experiment", "table", "--workers", "0"), "--workers", "0"),
    (("biped_controller.studies.experiment", "max-push", "--resolution", "inf"), "--resolution", "inf"),
    (("biped_controller.studies.experiment", "walk", "--profile", "no_such_profile"), "--profile", "known profiles"),
    (("biped_controller.studies.experiment", "walk", "--set", "Kp=-1"), "Kp", "-1"),
    (("biped_controller.studies.capability_map", "--workers", "0"), "--workers", "0"),
    (("biped_controller.studies.capability_map", "--profile", "nope"), "--profile", "known profiles"),
    (("biped_controller.studies.robustness", "--profile", "nope"), "--profile", "known profiles"),
    (("biped_controller.studies.plant_compare", "push", "--force", "inf"), "--force", "inf"),
]


@pytest.mark.parametrize("argv,option,value", BAD_VALUES, ids=[" ".join(a[0][1:]) for a in BAD_VALUES])
def test_a_bad_value_is_one_line_naming_it_with_exit_status_2(argv, option, value):
    r = _cli(*argv)
    assert r.returncode == 2, (r.returncode, r.stdout[-500:], r.stderr[-2000:])
    assert "Traceback" not in r.stderr, r.stderr[-2000:]
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert len(lines) == 1, r.stderr
    assert option in lines[0] and value in lines[0], lines[0]


def test_the_profile_is_printed_with_only_the_differing_settings(capsys):
    ts.print_settings(ts.parse_overrides(["Kp=900"], profile="paper"))
    assert capsys.readouterr().out == "profile paper; settings differing from config/: Kp=900, disturbance_observer=False\n"
    ts.print_settings(ts.run_settings("delay2"))
    out = capsys.readouterr().out.splitlines()
    assert out == ["profile delay2; settings differing from config/: delay_compensation=2, momentum_observer=True",
                   "plant perturbation: delay=2"], out


# ------------------------------------------------------------------------------------------ nodes
def test_the_nodes_take_a_profile_and_explicit_parameters_win(rclpy_context):
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from biped_controller.graph.controller_node import read_controller_config
    from biped_sim.graph.simulator_node import read_perturbation, read_sim_config
    from biped_model.description import load_description

    def node(name, **params):
        return Node(name, context=rclpy_context,
                    parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    n = node("controller", profile="real-sensors", Kp=900.0)
    cfg = read_controller_config(n)
    want = ts.parse_overrides(["Kp=900"], profile="real-sensors").ctrl_config(cfg.mode)
    assert cfg == want and cfg.state_estimator and cfg.momentum_observer_gain == 50.0
    n.destroy_node()
    assert read_controller_config(node("controller")).disturbance_observer is True      # default profile
    s = node("simulator", profile="delay2")
    assert read_sim_config(s) == ts.DEFAULT_SETTINGS.sim_config()
    assert read_perturbation(s, load_description()).delay == 2
    s = node("simulator", profile="real-sensors-mujoco")
    assert read_sim_config(s).plant == "mujoco"
