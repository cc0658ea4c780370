"""How quiet the stance foot is, per control period, on either plant. Pure Python on ``runner.run`` (no ROS).

Usage::

    python -m lab.foot_quiet [--plant rigid|mujoco] [--mode both] [--steps 10]
        [--set KEY=VALUE ...] [--observer on|off] [--perturb FIELD=VALUE ...] [--integration-rate] [--json FILE]

One undisturbed walk, then, over the control periods that
start at least ``skip`` (10 ms) after the run's start or after a touchdown, from each period's record
(``StepRecord``: ``wrench`` = [F_x, F_z, m] of the ground on the robot over the period, ``cop`` = m / F_z
[m] ahead of the stance ankle, ``x`` the floating state at the period's start):

* ``unloaded``: share of periods with the stance normal force F_z below ``f_min`` (20 N);
* ``edge``: share of periods whose centre of pressure lies within ``band`` (1 mm) of the heel (``l_min``) or
  the toe (``l_max``), or outside the sole, or is undefined (F_z <= 0);
* ``dfz_p99`` [N]: the 99th percentile of |F_z(k) - F_z(k-1)| over consecutive counted periods of one stance;
* ``max_pitch`` [rad]: the largest |pitch| of the stance foot (torso pitch + the stance leg's three joints,
  counter-clockwise) at the counted periods' starts;

and the same per bin of the time since the last touchdown (``bin`` = 25 ms wide; the first bin holds the
counted periods of its last 15 ms only). A rigid-plant period's wrench is the ground reaction of that
period's model (the rigid foot cannot rock); a MuJoCo period's is the mean of the contact forces over its
MuJoCo steps (``biped_sim.plant.mujoco``).

``--set`` takes any key of ``config/controller.yaml`` (but ``mode``) or ``config/simulator.yaml``, as
``scripts/experiment`` does; ``--plant`` is the simulator's ``plant`` key; ``--perturb`` a field of the plant's
``PlantPerturbation`` (the plant's model only, e.g. ``foot_inertia_scale=10``); ``--integration-rate`` evaluates
the controller's torque law at every integration step (MuJoCo step) instead of holding it over the period.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from biped_model.description import LEFT, load_description
from biped_controller.closed_loop import runner

#: the measurement's defaults: a period counts after SKIP [s] past a touchdown; F_MIN [N] the unloaded
#: threshold (the MuJoCo plant's foot switch); BAND [m] the edge band (the rigid plant's tip boundary seen
#: through a soft corner); BIN [s] the phase bins
SKIP, F_MIN, BAND, BIN = 0.010, 20.0, 1e-3, 0.025


@dataclass(frozen=True)
class PeriodSeries:
    """The counted periods of a run: their start time [s], time since the last touchdown [s], stance index,
    index of the stance (0 before the first touchdown, +1 at each), F_z [N], centre of pressure [m], stance
    foot pitch [rad]."""

    t: np.ndarray
    since: np.ndarray
    stance: np.ndarray
    support: np.ndarray
    fz: np.ndarray
    cop: np.ndarray
    pitch: np.ndarray


def stance_pitch(x: np.ndarray, stance: np.ndarray) -> np.ndarray:
    """Pitch [rad] of the stance foot, counter-clockwise: torso pitch + the stance leg's hip, knee, ankle
    (floating state ``x = [x_hip, z_hip, theta, lh, lk, la, rh, rk, ra]``, one row per period)."""
    return np.where(stance == LEFT, x[:, 2] + x[:, 3:6].sum(1), x[:, 2] + x[:, 6:9].sum(1))


def period_series(records, impact_times, skip: float = SKIP) -> PeriodSeries:
    """The periods of ``records`` that start at least ``skip`` [s] after the run's first period or the last
    touchdown before them (``impact_times`` [s], increasing)."""
    recs = list(records)
    if not recs:
        raise ValueError("no records: the run simulated no period")
    t = np.array([r.t for r in recs])
    touch = np.concatenate(([t[0]], np.asarray(impact_times, dtype=float)))
    k = np.searchsorted(touch, t, side="right") - 1
    since = t - touch[k]
    keep = since >= skip - 1e-9
    W = np.array([r.wrench for r in recs])
    st = np.array([r.stance for r in recs])
    X = np.array([r.x for r in recs])
    return PeriodSeries(t=t[keep], since=since[keep], stance=st[keep], support=k[keep], fz=W[keep, 1],
                        cop=np.array([r.cop for r in recs])[keep], pitch=stance_pitch(X, st)[keep])


def figures(s: PeriodSeries, l_min: float, l_max: float, f_min: float = F_MIN, band: float = BAND) -> dict:
    """The four figures of the module docstring over the periods of ``s`` (JSON-ready; None where empty)."""
    n = len(s.t)
    if n == 0:
        return {"periods": 0, "unloaded": None, "edge": None, "dfz_p99": None, "dfz_max": None, "max_pitch": None,
                "fz_mean": None, "cop_mean": None}
    cop = np.where(s.fz > 0.0, s.cop, np.nan)
    inside = (cop > l_min + band) & (cop < l_max - band)          # NaN compares False: undefined = at an edge
    # consecutive counted periods of the same support phase (a cut in the series is not a change between periods)
    same = (np.diff(s.support) == 0) & (np.diff(s.t) < 1.5 * np.median(np.diff(s.t))) if n > 1 else np.zeros(0, bool)
    dfz = np.abs(np.diff(s.fz))[same] if n > 1 else np.zeros(0)
    return {"periods": int(n),
            "unloaded": float(np.mean(s.fz < f_min)),
            "edge": float(np.mean(~inside)),
            "dfz_p99": float(np.percentile(dfz, 99)) if len(dfz) else None,
            "dfz_max": float(np.max(dfz)) if len(dfz) else None,
            "max_pitch": float(np.max(np.abs(s.pitch))),
            "fz_mean": float(np.mean(s.fz)),
            "cop_mean": float(np.nanmean(cop)) if np.any(np.isfinite(cop)) else None}


def binned(s: PeriodSeries, l_min: float, l_max: float, width: float = BIN, **kw) -> list[dict]:
    """:func:`figures` per bin [k width, (k + 1) width) of the time since the last touchdown."""
    b = np.floor(s.since / width + 1e-9).astype(int)
    out = []
    for k in range(int(b.max()) + 1 if len(b) else 0):
        m = b == k
        if not m.any():
            continue
        sub = PeriodSeries(*(getattr(s, f)[m] for f in PeriodSeries.__dataclass_fields__))
        out.append({"from": round(k * width, 9), "to": round((k + 1) * width, 9), **figures(sub, l_min, l_max, **kw)})
    return out


def measure(result: "runner.RunResult", skip: float = SKIP, f_min: float = F_MIN, band: float = BAND,
            width: float = BIN) -> dict:
    """The figures of a run (``runner.run``'s result): overall and per phase bin, plus the run's outcome."""
    foot = load_description().foot
    s = period_series(result.records, [i.t for i in result.impacts], skip)
    return {"steps_walked": result.steps_walked, "fallen": result.fallen, "fall_cause": result.fall_cause,
            "skip": skip, "f_min": f_min, "band": band, "bin": width,
            "overall": figures(s, foot.l_min, foot.l_max, f_min, band),
            "by_phase": binned(s, foot.l_min, foot.l_max, width, f_min=f_min, band=band)}


def run_figures(plant: str = "mujoco", mode: str = "both", steps: int = 10, overrides: tuple[str, ...] = (),
                observer: str | None = None, perturb: tuple[str, ...] = (), integration_rate: bool = False) -> dict:
    """One undisturbed walk (``--set`` style ``overrides``, ``--perturb`` style ``perturb``) and its figures
    (:func:`measure`)."""
    from biped_controller.studies.trial.settings import parse_overrides, parse_perturbation
    settings = parse_overrides(tuple(overrides) + (f"plant={plant}",), observer=observer)
    scfg = settings.sim_config()
    r = runner.run(steps=steps, mode=mode, sim_config=scfg, ctrl_config=settings.ctrl_config(mode),
                   perturbation=parse_perturbation(tuple(perturb)), integration_rate=integration_rate)
    out = {"plant": plant, "mode": mode, "steps": steps, "overrides": list(overrides), "observer": observer,
           "perturb": list(perturb), "integration_rate": integration_rate}
    out.update(measure(r))
    return out


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.1f} %"


def _num(v, fmt: str) -> str:
    return "-" if v is None else format(v, fmt)


def table(res: dict) -> str:
    """The figures as text: one summary line, then one line per phase bin."""
    o = res["overall"]
    head = (f"{res['plant']} mode {res['mode']}, {res['steps_walked']} steps"
            + (f", fell ({res['fall_cause']})" if res["fallen"] else "")
            + f"; periods counted (>= {1e3 * res['skip']:.0f} ms after a touchdown): {o['periods']}\n"
            f"  F_z < {res['f_min']:g} N: {_pct(o['unloaded'])}   CoP within {1e3 * res['band']:g} mm of heel/toe: "
            f"{_pct(o['edge'])}   |dF_z| p99: {_num(o['dfz_p99'], '.0f')} N (max {_num(o['dfz_max'], '.0f')} N)   "
            f"max foot pitch: {_num(o['max_pitch'], '.4f')} rad")
    lines = [head, "  since touchdown [s] | periods | F_z < min | CoP at edge | |dF_z| p99 [N] | mean F_z [N] | "
                   "mean CoP [mm] | max pitch [rad]"]
    for b in res["by_phase"]:
        lines.append(f"  {b['from']:.3f}-{b['to']:.3f} | {b['periods']} | {_pct(b['unloaded'])} | {_pct(b['edge'])} | "
                     f"{_num(b['dfz_p99'], '.0f')} | {_num(b['fz_mean'], '.1f')} | "
                     f"{_num(None if b['cop_mean'] is None else 1e3 * b['cop_mean'], '.1f')} | "
                     f"{_num(b['max_pitch'], '.4f')}")
    return "\n".join(lines)


def provenance(argv: list[str]) -> dict:
    """Where a result came from: the commit and modified files, the command line, the date, the load."""
    from biped_controller.studies.provenance import git_state
    return {**git_state(), "command": "python -m lab.foot_quiet " + " ".join(argv),
            "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "load_average": list(os.getloadavg())}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(prog="python -m lab.foot_quiet", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--plant", choices=("rigid", "mujoco"), default="mujoco")
    ap.add_argument("--mode", default="both")
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--observer", choices=("on", "off"), default=None)
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="override a key of config/controller.yaml or config/simulator.yaml (repeatable)")
    ap.add_argument("--perturb", action="append", default=[], metavar="FIELD=VALUE",
                    help="a field of the plant's PlantPerturbation, e.g. foot_inertia_scale=10 (repeatable)")
    ap.add_argument("--integration-rate", action="store_true",
                    help="the torque law evaluated at every integration step (no zero-order hold)")
    ap.add_argument("--json", type=Path, default=None, help="write the figures with their provenance here")
    a = ap.parse_args(argv)
    if a.steps < 1:
        ap.error(f"--steps must be >= 1, got {a.steps}")
    if any(o.partition("=")[0].strip() == "plant" for o in a.overrides):
        ap.error("--set plant=...: use --plant")
    from biped_controller.studies import provenance as records
    from biped_controller.studies.trial.settings import OverrideError
    run = records.Run(argv, plant=a.plant, profile="default")
    try:
        res = run_figures(a.plant, a.mode, a.steps, tuple(a.overrides), a.observer, tuple(a.perturb),
                          a.integration_rate)
    except (OverrideError, ValueError) as exc:
        print(f"foot_quiet: {exc}", file=sys.stderr)
        return 2
    if a.json is not None:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps({"provenance": provenance(argv), **res}, indent=1) + "\n", encoding="utf-8")
        run.record(a.json)      # the record in the directory's provenance.json (results/README.md)
    print(table(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
