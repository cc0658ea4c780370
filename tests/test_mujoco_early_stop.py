"""The MuJoCo plant's early stop (``trial.stop.MujocoEarlyStop``): a trial it ends has the verdict of the same
trial run in full (a fall, a settled survival, a survival ended several steps early); its settings are
checked naming the key; it is its own plant's (the rigid plant's early stop and store fingerprint are
unchanged by it); each tolerance of the criterion binds."""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from biped_sim.plant.perturbation import PlantPerturbation
from biped_model.settings import default_config_dir

from biped_controller.studies import capability_map as cm
from biped_controller.studies.trial import context as tcontext
from biped_controller.studies.trial import runs, stop, trials
from biped_controller.studies.trial import settings as ts
from biped_controller.studies.trial.survival import Band

MUJOCO = ts.parse_overrides(["plant=mujoco"])
MUJOCO_FULL = dataclasses.replace(MUJOCO, full_trials=True)

# (mode, signed force [N], duration [s], onset phase): MuJoCo trials of the default map's cells (0.125 ms step,
# results/capability_map_mujoco/summary.json): survivals well inside and at a cell's boundary, a fall
# just above it (before the first touchdown after the push), a backward push, a fall four touchdowns after it
CASES = [("both", 390.625, 0.025, 0.5), ("both", 781.25, 0.025, 0.5), ("both", 784.375, 0.025, 0.5),
         ("tau", -300.0, 0.025, 0.3), ("none", 50.0, 0.025, 0.5), ("p", 456.25, 0.025, 0.9)]


def _push(force, duration, phase):
    return runs.paper_push(force, start=phase * tcontext.context().family.T, duration=duration)


@pytest.mark.parametrize("mode,force,duration,phase", CASES)
def test_the_mujoco_early_stop_gives_the_full_trials_verdict(mode, force, duration, phase):
    """Early stop on and off: the same verdict, reason, fall cause and time; a survival is decided before
    the trial's last impact, a failure runs as long as in full."""
    push = _push(force, duration, phase)
    a = trials.survives(push, mode, MUJOCO, pool=False)
    b = trials.survives(push, mode, MUJOCO_FULL, pool=False)
    assert b["decided_at_step"] is None
    assert (a["survived"], a["fell"], a["reason"], a["fall_cause"], a["fall_time"]) == \
           (b["survived"], b["fell"], b["reason"], b["fall_cause"], b["fall_time"]), (mode, force)
    if a["survived"]:
        assert a["decided_at_step"] is not None and a["decided_at_step"] < b["steps_walked"] - 2, a
    else:
        assert a["decided_at_step"] is None and a["steps_walked"] == b["steps_walked"]


#: (mode, signed force [N], duration [s], phase): a MuJoCo push after which the robot walks four impacts after the
#: push's end and then falls (foot_rotated at t = 2.12 s; results/mujoco_sweeps/early_stop_orbit.json)
LATE_FALL = ("p", 456.25, 0.025, 0.9)


def test_loose_mujoco_tolerances_would_decide_a_fall_survived(monkeypatch):
    """Negative control: with every tolerance unbounded a trial is decided one period after its first impact
    after the push, and a push after which the robot falls a step later is reported survived: the
    comparison above can fail, the tolerances matter."""
    push = _push(*LATE_FALL[1:])
    full = trials.survives(push, LATE_FALL[0], MUJOCO_FULL, pool=False)
    assert full["fell"] and full["steps_walked"] > runs.push_step_index(push, tcontext.context().family.T)
    es = stop.mujoco_early_stop()
    inf = math.inf
    loose = dataclasses.replace(es, q=inf, qd=inf, band=inf, p_dot_rate=inf, force=inf, lam=inf, lam_dot=inf)
    monkeypatch.setattr(stop, "mujoco_early_stop", lambda: loose)
    got = trials.survives(push, LATE_FALL[0], MUJOCO, pool=False)
    assert got["survived"] and got["decided_at_step"] is not None


def test_each_plant_has_its_own_early_stop(monkeypatch):
    """The rigid criterion never ends a MuJoCo trial and the MuJoCo criterion never a rigid one; a perturbed
    plant's trial runs in full on either plant."""
    monkeypatch.setattr(stop.EarlyStop, "decided", lambda self, sim, ctrl, end, fam: True)
    monkeypatch.setattr(stop.MujocoEarlyStop, "decided", lambda self, sim, ctrl, end, fam, band, dt: False)
    push = runs.paper_push(100.0)
    rigid = trials.survives(push, "both", ts.DEFAULT_SETTINGS, pool=False)
    assert rigid["decided_at_step"] is not None and rigid["decided_at_step"] < runs.trial_steps(push)
    assert trials.survives(push, "both", MUJOCO, pool=False)["decided_at_step"] is None
    monkeypatch.setattr(stop.EarlyStop, "decided", lambda self, sim, ctrl, end, fam: False)
    monkeypatch.setattr(stop.MujocoEarlyStop, "decided", lambda self, sim, ctrl, end, fam, band, dt: True)
    assert trials.survives(push, "both", ts.DEFAULT_SETTINGS, pool=False)["decided_at_step"] is None
    mj = trials.survives(push, "both", MUJOCO, pool=False)
    assert mj["decided_at_step"] == runs.push_step_index(push, tcontext.context().family.T) + 1
    assert stop.applies_mujoco(MUJOCO) and not stop.applies_mujoco(ts.DEFAULT_SETTINGS)
    assert not stop.applies(MUJOCO) and stop.applies(ts.DEFAULT_SETTINGS)
    bent = dataclasses.replace(MUJOCO, perturbation=PlantPerturbation(torso_mass_scale=1.1))
    assert not stop.applies_mujoco(bent)


def test_the_mujoco_settings_are_checked_naming_the_key(tmp_path):
    src = (Path(default_config_dir()) / "studies.yaml").read_text()
    p = tmp_path / "studies.yaml"
    for key, bad in (("early_stop_mujoco_q", "-1.0"), ("early_stop_mujoco_qd", ".nan"),
                     ("early_stop_mujoco_band", "1.5"), ("early_stop_mujoco_band", "0"),
                     ("early_stop_mujoco_p_dot_rate", "true"), ("early_stop_mujoco_force", "'many'"),
                     ("early_stop_mujoco", "3")):
        lines = [f"{key}: {{value: {bad}, reason: \"bad\"}}" if ln.startswith(key + ":") else ln
                 for ln in src.splitlines()]
        p.write_text("\n".join(lines) + "\n")
        with pytest.raises(stop.StudySettingsError, match=f"'{key}'"):
            stop.MujocoEarlyStop.load(p)
    assert stop.MujocoEarlyStop.load() == stop.mujoco_early_stop()


def test_the_mujoco_settings_are_in_the_mujoco_store_fingerprint_only(monkeypatch):
    """A MuJoCo store is not resumed across other MuJoCo tolerances; a rigid store's fingerprint hashes the
    rigid early stop's settings exactly as before (``asdict(EarlyStop)``), untouched by the MuJoCo ones."""
    from dataclasses import asdict
    spec = cm.MapSpec(modes=("both",), directions=("forward",), phases=(0.5,), durations=(0.025,))
    mspec = dataclasses.replace(spec, settings=MUJOCO)
    rigid, mj = cm.fingerprint(spec), cm.fingerprint(mspec)
    assert stop.identity(ts.DEFAULT_SETTINGS) == asdict(stop.early_stop())
    es = stop.mujoco_early_stop()
    monkeypatch.setattr(stop, "mujoco_early_stop", lambda: dataclasses.replace(es, q=2 * es.q))
    assert cm.fingerprint(mspec) != mj and cm.fingerprint(spec) == rigid


def test_mujoco_criterion_checks_every_tolerance_and_the_push_end():
    """``MujocoEarlyStop.inside`` on distances just inside every tolerance holds; each one just outside (or a
    touchdown period starting before the push's end) makes it fail; p and tau' are held to the fraction
    ``band`` of the trial's band."""
    es = stop.mujoco_early_stop()
    band = Band(2e-3, 8e-3, 1e-3, 4e-3)
    tol = {"q": es.q, "q_in": es.q, "qd_in": es.qd, "p": es.band * band.p_tol, "tau_dot": es.band * band.tau_dot_tol,
           "p_dot": es.p_dot_rate * es.band * band.p_tol, "force": es.force, "lam": es.lam, "lam_dot": es.lam_dot}
    d = {k: 0.9 * v for k, v in tol.items()} | {"after_push": True, "qd": 10.0, "delay": 1e-3}
    assert es.inside(d, band)
    for k, v in tol.items():
        assert not es.inside(d | {k: 1.1 * v}, band), k
    assert not es.inside(d | {"after_push": False}, band)
    assert not es.inside(d, Band(1e-3, 1e-3, 0.0, 0.0))          # the floors' band: p, tau' too far
