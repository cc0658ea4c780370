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


# ------------------------------------------------------------------ the early stop under sensor noise
NOISY = ts.run_settings("real-sensors-mujoco")

# (mode, force [N], onset phase, seed index): trials of the 25 ms forward slice under real-sensors-mujoco, its cell's
# seed index i (results/uncertainty/noisy_early_stop/forward_mixed.json): a survival the criterion decides at the
# second touchdown, a fall of the same batch, and mode both's survival decided at the ninth of eleven
NOISY_CASES = [("wbc", 400.0, 0.25, 10), ("wbc", 400.0, 0.25, 5), ("both", 550.0, 0.0, 2)]


def _noisy(phase: float, index: int):
    from biped_controller.studies.trial import seeded, uncertainty
    T = tcontext.context().family.T
    cell = seeded.cell_of(NOISY, start=phase * T, duration=0.025, sign=1.0, height=None)
    return seeded.seeded_settings(NOISY, uncertainty.trial_seed(cell, index))


@pytest.mark.parametrize("mode,force,phase,index", NOISY_CASES)
def test_under_sensor_noise_the_mujoco_early_stop_gives_the_full_trials_verdict(mode, force, phase, index):
    """A seeded trial of the noisy profile with the early stop and in full: the same verdict, reason, fall
    cause and time; the survival is decided before the trial's end, the fall runs as long as in full."""
    s = _noisy(phase, index)
    push = _push(force, 0.025, phase)
    a = trials.survives(push, mode, s, pool=False)
    b = trials.survives(push, mode, dataclasses.replace(s, full_trials=True), pool=False)
    assert b["decided_at_step"] is None
    assert (a["survived"], a["fell"], a["reason"], a["fall_cause"], a["fall_time"]) == \
           (b["survived"], b["fell"], b["reason"], b["fall_cause"], b["fall_time"]), (mode, force, index)
    if a["survived"]:
        assert a["decided_at_step"] is not None and a["decided_at_step"] < b["steps_walked"], a
    else:
        assert a["decided_at_step"] is None and a["steps_walked"] == b["steps_walked"]


def test_the_noisy_early_stop_applies_to_sensor_noise_on_mujoco_only(monkeypatch):
    """It applies to a nominal MuJoCo plant with sensor noise and no delay, switched on; not to the rigid plant's
    noise, a model error, a delay, full trials or the switch off; its store identity says so."""
    assert stop.applies_mujoco_sensors(NOISY) and not stop.applies_mujoco(NOISY) and stop.stops_early(NOISY)
    assert not stop.applies_mujoco_sensors(MUJOCO) and stop.applies_mujoco(MUJOCO)
    assert not stop.applies_mujoco_sensors(ts.run_settings("real-sensors"))
    pert = NOISY.perturbation
    for bad in (dataclasses.replace(pert, torso_mass_scale=1.1), dataclasses.replace(pert, delay=1),
                dataclasses.replace(pert, mu=0.5)):
        assert not stop.applies_mujoco_sensors(dataclasses.replace(NOISY, perturbation=bad)), bad
    assert not stop.stops_early(dataclasses.replace(NOISY, full_trials=True))
    assert stop.identity(NOISY) == {**stop.mujoco_early_stop().identity(), "sensors": list(stop.sensors_modes())}
    assert stop.applies_mujoco_sensors(NOISY, "both") and not stop.applies_mujoco_sensors(NOISY, "p")
    monkeypatch.setattr(stop, "sensors_switch", lambda: False)
    assert not stop.applies_mujoco_sensors(NOISY) and not stop.stops_early(NOISY)
    assert stop.identity(NOISY) == stop.mujoco_early_stop().identity()


# the paper's cell under real-sensors-mujoco (results/uncertainty/paper_cell/compare_seeds32_stopped_full.json):
# mode p at 50 N, seed index 6, falls at 4.84 s in full after a touchdown the criterion decides; mode none at 0 N,
# seed index 1, whose seed's unpushed walk falls
P_LATE_FALL = ("p", 50.0, 6)
NONE_UNPUSHED_FALL = ("none", 0.0, 1)


def _paper_cell(index: int):
    from biped_controller.studies.trial import seeded, uncertainty
    cell = seeded.cell_of(NOISY, start=runs.DEFAULT_START, duration=runs.DEFAULT_DURATION, sign=1.0, height=None)
    return seeded.seeded_settings(NOISY, uncertainty.trial_seed(cell, index))


def test_under_noise_the_stop_leaves_modes_it_does_not_hold_for_and_fallen_seeds(monkeypatch):
    """Mode p (not in ``early_stop_mujoco_sensors_modes``) runs in full and falls late; with p added to the
    list the criterion would decide that trial survived (the negative control: the list matters). A seed whose
    unpushed walk fell is never stopped, even for a mode in the list."""
    mode, force, index = P_LATE_FALL
    s = _paper_cell(index)
    push = runs.paper_push(force)
    got = trials.survives(push, mode, s, pool=False)
    assert got["fell"] and got["decided_at_step"] is None and got["fall_time"] > 4.0, got
    monkeypatch.setattr(stop, "sensors_modes", lambda: ("both", "p", "tau", "wbc"))
    wrong = trials.survives(push, mode, s, pool=False)
    assert wrong["survived"] and wrong["decided_at_step"] is not None
    monkeypatch.setattr(stop, "sensors_modes", lambda: ("both", "none", "p", "tau", "wbc"))
    mode, force, index = NONE_UNPUSHED_FALL
    s = _paper_cell(index)
    push = runs.paper_push(force)
    assert trials.band(mode, push, s).unpushed_fall
    got = trials.survives(push, mode, s, pool=False)
    assert got["fell"] and got["decided_at_step"] is None


def test_the_sensors_modes_must_be_built_in_modes(tmp_path, monkeypatch):
    """``early_stop_mujoco_sensors_modes`` that is not a list of built-in modes stops the study naming the key."""
    src = (Path(default_config_dir()) / "studies.yaml").read_text()
    for bad in ("both", "[both, walk]"):
        lines = [f"early_stop_mujoco_sensors_modes: {{value: {bad}, reason: \"bad\"}}"
                 if ln.startswith("early_stop_mujoco_sensors_modes:") else ln for ln in src.splitlines()]
        (tmp_path / "studies.yaml").write_text("\n".join(lines) + "\n")
        monkeypatch.setattr(stop, "default_config_dir", lambda: tmp_path)
        with pytest.raises(stop.StudySettingsError, match="'early_stop_mujoco_sensors_modes'"):
            stop.sensors_modes()


def test_the_sensors_switch_must_be_a_boolean(tmp_path, monkeypatch):
    """``early_stop_mujoco_sensors`` that is not true or false stops the study naming the key."""
    src = (Path(default_config_dir()) / "studies.yaml").read_text()
    lines = ["early_stop_mujoco_sensors: {value: 1, reason: \"bad\"}" if ln.startswith("early_stop_mujoco_sensors:")
             else ln for ln in src.splitlines()]
    (tmp_path / "studies.yaml").write_text("\n".join(lines) + "\n")
    monkeypatch.setattr(stop, "default_config_dir", lambda: tmp_path)
    with pytest.raises(stop.StudySettingsError, match="'early_stop_mujoco_sensors'"):
        stop.sensors_switch()


def test_a_seeded_cell_stopped_early_has_its_own_store_key():
    """The seeded map's cell key names the early stop where it ends noisy trials; with ``--full-trials`` the
    key is the one every store made before that stop had (its fields unchanged)."""
    from biped_controller.studies.capmap import seeded as cms
    spec = cm.MapSpec(modes=("both", "wbc"), directions=("forward",), phases=(0.5,), durations=(0.025,),
                      settings=NOISY)
    full = dataclasses.replace(spec, settings=dataclasses.replace(NOISY, full_trials=True))
    k, kf = cms._key(spec, "forward", 0.5, 0.025, 16, (0.9, 0.5)), cms._key(full, "forward", 0.5, 0.025, 16, (0.9, 0.5))
    assert k["early_stop"] == stop.identity(NOISY) and "early_stop" not in kf
    assert sorted(kf) == ["coarse", "direction", "duration", "height", "levels", "max", "modes", "phase",
                          "resolution", "seeds", "settings"]
    assert {a: b for a, b in k.items() if a != "early_stop"} == kf


def test_a_band_handed_to_the_process_is_the_one_its_trials_use(monkeypatch):
    """``trials.give_band``: the band of (mode, push, settings) handed in is what ``trials.band`` returns, without
    the walk being run here; another seed's band is still its own walk's; a plug-in controller ignores it."""
    from biped_controller.studies.trial import controller as tc
    push = runs.paper_push(100.0)
    s = _noisy(0.5, 0)
    mine = Band(0.5, 0.25, 0.1, 0.05)
    trials.give_band("wbc", push, s, mine)
    monkeypatch.setattr(tc, "_walk_band", lambda *a: (_ for _ in ()).throw(AssertionError("walk run again")))
    assert trials.band("wbc", push, s) is mine
    with pytest.raises(AssertionError, match="walk run again"):
        trials.band("wbc", push, _noisy(0.5, 1))
    tc.TrialController.give_band(tc.resolve("wbc"), s, 3, mine)       # the interface's default: ignored
