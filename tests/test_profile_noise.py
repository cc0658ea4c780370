"""The real-sensor profiles put their design-point noise on the plant (issue 43: seeds need something to
sample); ``--perturb none`` drops it. Every committed command that used a real-sensor profile, re-parsed
with today's code, gives the settings its file recorded (the 16 without noise carry ``--perturb none``)."""
from __future__ import annotations

import argparse
import json
import shlex
from pathlib import Path

import pytest

from biped_controller.studies import experiment as ex
from biped_controller.studies.trial import seeded
from biped_controller.studies.trial import settings as ts

ROOT = Path(__file__).resolve().parents[1]
NOISE = {"noise_q": 5e-4, "noise_qd": 5e-2, "encoder_bits": 14}


def _settings_of(command: str) -> dict:
    """The JSON form of ``trial.settings.differences`` of a recorded command's settings flags."""
    ap = argparse.ArgumentParser(add_help=False)
    for flag in ("--profile", "--observer", "--robot"):
        ap.add_argument(flag)
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    ap.add_argument("--perturb", action="append", default=[])
    a, _ = ap.parse_known_args(shlex.split(command))
    s = ts.run_settings(a.profile, a.overrides, a.observer, a.perturb, robot=a.robot)
    return json.loads(json.dumps(ts.differences(s)))


def _real_sensor_commands() -> list[tuple[Path, str]]:
    out = []
    for prov in sorted(ROOT.glob("results/**/provenance.json")):
        for name, rec in json.loads(prov.read_text()).items():
            cmd = rec.get("command") or ""
            if "studies.experiment" in cmd and "--profile real-sensors" in cmd and name.endswith(".json"):
                out.append((prov.parent / name, cmd))
    return out


def test_the_profiles_put_their_noise_on_the_plant():
    for prof, plant in (("real-sensors", "rigid"), ("real-sensors-mujoco", "mujoco")):
        s = ts.run_settings(prof)
        assert s.sim_config().plant == plant
        cfg = s.ctrl_config("both")            # the plant's noise is what the controller assumes
        assert (s.perturbation.noise_q, s.perturbation.noise_qd, s.perturbation.encoder_bits) == \
            (cfg.sensor_noise_q, cfg.sensor_noise_qd, cfg.sensor_encoder_bits) == tuple(NOISE.values())
        assert seeded.is_random(s)
        # the same noise given by hand is the same settings; none drops it, and fields apply after it
        assert ts.run_settings(prof, perturb=[f"{k}={v}" for k, v in NOISE.items()]) == s
        assert ts.run_settings(prof, perturb=["none"]).perturbation is None
        assert not seeded.is_random(ts.run_settings(prof, perturb=["none"]))
        t = ts.run_settings(prof, perturb=["torso_mass_scale=0.8", "none"]).perturbation
        assert t.torso_mass_scale == 0.8 and t.noise_q == 0.0 and t.encoder_bits == 0
        assert ts.run_settings(prof, perturb=["noise_q=1e-3"]).perturbation.noise_qd == NOISE["noise_qd"]
    for prof in ("paper", "default"):        # the ideal profiles draw nothing, none changes nothing
        assert ts.run_settings(prof).perturbation is None
        assert ts.run_settings(prof, perturb=["none"]) == ts.run_settings(prof)


def test_perturb_none_twice_is_one_line_exit_2(capsys):
    with pytest.raises(SystemExit) as e:
        ex.main(["walk", "--profile", "real-sensors", "--perturb", "none", "--perturb", "none"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--perturb none" in err


def test_committed_real_sensor_commands_keep_their_settings():
    cmds = _real_sensor_commands()
    assert len(cmds) >= 24 and sum("--perturb none" in c for _, c in cmds) >= 16
    for path, cmd in cmds:
        assert _settings_of(cmd) == json.loads(path.read_text())["settings"], path


def test_a_command_without_the_override_is_caught():
    """Negative control: a noiseless committed command with ``--perturb none`` taken out now differs."""
    path, cmd = next((p, c) for p, c in _real_sensor_commands() if p.name == "nominal_settle3.json")
    assert _settings_of(cmd.replace(" --perturb none", "")) != json.loads(path.read_text())["settings"]
