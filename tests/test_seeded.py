"""The max-push table over seeds (studies.trial.seeded, ``scripts/experiment table --seeds N``): bad input
refused in one line (exit 2), deterministic settings left to the one-trial-per-force search, a seeded trial
re-run alone equal to its record, and the search's bookkeeping (seeds counted apart, crossings) on a
synthetic survival curve in place of the simulator."""
from __future__ import annotations

import math

import numpy as np
import pytest

from biped_controller.studies import experiment as ex
from biped_controller.studies.trial import seeded, trials, uncertainty
from biped_controller.studies.trial import settings as ts
from biped_controller.studies.trial.runs import paper_push

NOISE = ["noise_q=5e-4", "noise_qd=5e-2", "encoder_bits=14"]


@pytest.mark.parametrize("argv,needle", [
    (["table", "--seeds", "0"], "--seeds"), (["table", "--seeds", "-3"], "--seeds"),
    (["table", "--seeds", "2.5"], "--seeds"), (["max-push", "--seeds", "x"], "--seeds"),
    (["table", "--seeds", "4", "--levels", "1.0"], "--levels"), (["table", "--levels", "0.9,0"], "--levels"),
    (["table", "--levels", "0.5,0.5"], "--levels"), (["table", "--levels", "nan"], "--levels"),
    (["table", "--seeds", "4", "--resolution", "0"], "--resolution"),
    (["table", "--seeds", "4", "--resolution", "-5"], "--resolution"),
    (["table", "--ray"], "--ray"), (["table", "--seeds", "4", "--profile", "real-sensors", "--perturb", "none", "--ray"], "--ray"),
])
def test_bad_seed_counts_levels_and_resolutions_are_one_line_exit_2(argv, needle, capsys):
    with pytest.raises(SystemExit) as e:
        ex.main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err


def test_only_noisy_settings_are_random():
    for prof in ("paper", "default", "delay2"):
        assert not seeded.is_random(ts.run_settings(prof))
    for prof in ("real-sensors", "real-sensors-mujoco"):      # the profile's own noise on the plant
        assert seeded.is_random(ts.run_settings(prof))
        assert not seeded.is_random(ts.run_settings(prof, perturb=["none", "torso_mass_scale=0.8"]))
    assert seeded.is_random(ts.run_settings("real-sensors", perturb=NOISE))


def test_deterministic_settings_ignore_seeds(monkeypatch, capsys):
    """--seeds on settings without noise: the same call of the deterministic search as without it."""
    calls = []

    def fake(modes, *a, **kw):
        calls.append((modes, a, {k: v for k, v in kw.items()}))
        return {m: {"mode": m} for m in modes}
    monkeypatch.setattr(ex, "max_push_modes", fake)
    monkeypatch.setattr(ex, "print_max_push", lambda res: None)
    monkeypatch.setattr(ex, "ordering_finding", lambda res: "")
    monkeypatch.setattr(ex, "seeded_table", lambda *a, **k: pytest.fail("seeded search on deterministic settings"))
    ex.main(["table", "--modes", "both", "--profile", "real-sensors", "--perturb", "none"])
    ex.main(["table", "--modes", "both", "--profile", "real-sensors", "--perturb", "none", "--seeds", "8"])
    assert len(calls) == 2 and calls[0] == calls[1]
    assert "draw nothing random" in capsys.readouterr().out


def test_a_seeded_trial_rerun_alone_equals_its_record():
    settings = ts.run_settings("real-sensors", perturb=NOISE)
    cell = seeded.cell_of(settings, start=0.2315, duration=0.025, sign=1.0, height=None)
    seed = uncertainty.trial_seed(cell, 1)
    push = paper_push(450.0, start=0.2315, duration=0.025)
    rec = seeded._task((push, "both", seeded.seeded_settings(settings, seed), 1))
    assert rec["seed"] == seed and rec["seed_index"] == 1 and rec["counted"] is True
    alone = trials.survives(push, "both", seeded.seeded_settings(settings, rec["seed"]), pool=None)
    assert {k: rec[k] for k in alone} == alone
    other = trials.survives(push, "both", seeded.seeded_settings(settings, uncertainty.trial_seed(cell, 2)), pool=None)
    assert other["seed"] != rec["seed"]


def _synthetic_trial(f50=400.0, width=30.0, fell_seed_index=3, fault_force=200.0):
    """A stand-in for ``seeded_trial``: seed index ``fell_seed_index`` has an unpushed walk that falls, one
    trial at ``fault_force`` ends in a controller fault; every other trial survives iff a uniform draw of
    default_rng([seed % 2**32, force in mN]) is below the logistic 1 / (1 + exp((F - f50) / width))."""
    def trial(push, mode, settings):
        f = abs(push.force)
        seed = settings.perturbation.seed
        ok = bool(np.random.default_rng([seed % 2**32, int(round(f * 1000))]).random()
                  < 1.0 / (1.0 + math.exp((f - f50) / width)))
        fell = fell_seed_index is not None and seed == SEEDS[fell_seed_index]
        fault = "step" if (f == fault_force and seed == SEEDS[0]) else None
        return {"force": push.force, "mode": mode, "survived": ok and not fell and fault is None, "seed": seed,
                "fault_kind": fault, "unpushed_fall": "fell: test" if fell else "",
                "counted": not fell and fault is None, "reason": "synthetic"}
    return trial


SETTINGS = ts.run_settings("real-sensors", perturb=NOISE)
CELL = seeded.cell_of(SETTINGS, start=0.2315, duration=0.025, sign=1.0, height=None)
SEEDS = [uncertainty.trial_seed(CELL, i) for i in range(16)]


def test_seeded_table_counts_apart_and_finds_the_crossings(monkeypatch):
    monkeypatch.setattr(seeded, "seeded_trial", _synthetic_trial())
    res = seeded.seeded_table(("both",), 16, resolution=10.0, fmax=1000.0, coarse=100.0, settings=SETTINGS,
                              progress=False)["both"]
    assert res["seed_list"] == SEEDS
    by_force = {r["force"]: r for r in res["rates"]}
    assert all(r["unpushed_falls"] == 1 for r in res["rates"])                 # the falling seed, never counted
    assert by_force[200.0]["faults"] == 1 and by_force[200.0]["counted"] == 14 and by_force[200.0]["excluded"] == 2
    assert by_force[0.0]["counted"] == 15 and by_force[0.0]["survived"] == 15
    for r in res["rates"]:
        assert (r["wilson_lo"], r["wilson_hi"]) == uncertainty.wilson(r["survived"], r["counted"])
    trial = _synthetic_trial()

    def rate(f):   # the dense grid's rate at f: the same seeds, the same draws
        recs = [trial(paper_push(f), "both", seeded.seeded_settings(SETTINGS, s)) for s in SEEDS]
        return sum(r["survived"] for r in recs) / sum(r["counted"] for r in recs)
    grid = np.arange(0.0, 1000.0 + 5.0, 5.0).tolist()
    rates = [rate(f) for f in grid]
    for c in res["crossings"]:
        true = 400.0 + 30.0 * math.log((1.0 - c["level"]) / c["level"])
        assert c["bracket"][1] - c["bracket"][0] <= 10.0
        # a crossing of the sampled curve on the dense grid lies within the resolution of the estimate
        grid_crossings = [f for f, a, b in zip(grid, rates, rates[1:]) if a >= c["level"] > b]
        assert min(abs(f - c["estimate"]) for f in grid_crossings) <= 10.0
        assert abs(c["estimate"] - true) <= 60.0
        assert c["interval"][1] is not None and c["interval"][1] >= true
    assert {t["seed"] for t in res["trials"]} == set(SEEDS)
    # the coarse scan stopped at the first batch below the lowest level: nothing tried past it
    assert max(by_force) < 600.0


def test_no_counted_trial_is_an_undefined_crossing_not_a_survival(monkeypatch, capsys):
    """Every seed's unpushed walk falls: no rate exists, so each crossing is undefined (not 'no force up to fmax
    had a rate below the level', which would read as a survival), and the search tries nothing past force 0."""
    def fell(push, mode, settings):
        return {"force": push.force, "mode": mode, "survived": False, "seed": settings.perturbation.seed,
                "fault_kind": None, "unpushed_fall": "fell: test", "counted": False, "reason": "synthetic"}
    monkeypatch.setattr(seeded, "seeded_trial", fell)
    res = seeded.seeded_table(("none",), 4, resolution=10.0, fmax=1000.0, coarse=100.0, settings=SETTINGS,
                              progress=False)["none"]
    assert [r["force"] for r in res["rates"]] == [0.0] and res["rates"][0]["counted"] == 0
    assert res["rates"][0]["unpushed_falls"] == 4
    for c in res["crossings"]:
        assert c["estimate"] is None and c["interval"] == [None, None] and c["note"].startswith("undefined")
    seeded.print_seeded({"none": res})
    out = capsys.readouterr().out
    assert "crossing 90 %: undefined: no trial counted" in out and "unbounded" not in out


def test_controllers_share_seeds_and_compare_paired(monkeypatch):
    """Two modes on a synthetic curve whose draw depends on (seed, force) only, survival 50 % at 400 N for
    both and 300 N for wbc: the same seeds for both modes, and at every common force the paired counts
    recounted here from the trial records, with Newcombe's paired interval."""
    base = {"both": _synthetic_trial(fell_seed_index=None, fault_force=-1.0),
            "wbc": _synthetic_trial(f50=300.0, fell_seed_index=None, fault_force=-1.0)}
    monkeypatch.setattr(seeded, "seeded_trial", lambda push, mode, s: base[mode](push, mode, s))
    res = seeded.seeded_table(("both", "wbc"), 16, resolution=25.0, fmax=800.0, coarse=100.0, settings=SETTINGS,
                              progress=False)
    assert res["both"]["seed_list"] == res["wbc"]["seed_list"] == SEEDS
    comp = res["both"]["comparisons"]
    assert comp == res["wbc"]["comparisons"] and len(comp) == 1 and (comp[0]["a"], comp[0]["b"]) == ("both", "wbc")
    rows = {r["force"]: r for r in comp[0]["forces"]}
    assert {0.0, 100.0, 200.0, 300.0} <= set(rows)
    for f, row in rows.items():
        a = {r["seed_index"]: r["survived"] for r in res["both"]["trials"] if r["force"] == f}
        b = {r["seed_index"]: r["survived"] for r in res["wbc"]["trials"] if r["force"] == f}
        counts = [sum(1 for i in a if (a[i], b[i]) == pair) for pair in ((True, True), (True, False), (False, True),
                                                                         (False, False))]
        assert [row["both"], row["a_only"], row["b_only"], row["neither"]] == counts
        assert row == {"force": f, **uncertainty.paired_difference(*counts)}
    assert rows[0.0]["difference"] == 0.0 and rows[0.0]["lo"] < 0.0 < rows[0.0]["hi"]
    assert any(r["lo"] > 0.0 for r in rows.values())     # both ahead of wbc somewhere, beyond the interval
