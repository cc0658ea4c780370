"""Rigid vs MuJoCo: the one-off comparisons of ``docs/mujoco_plant.md`` (moved out of
``biped_controller.studies.plant_compare``, which keeps the product's ``walk``, ``push``, ``pushes`` and
``fingerprint``). Run from the repository root::

    .venv/bin/python -m lab.plant_compare falls [--json F]
    .venv/bin/python -m lab.plant_compare cmap --rigid STORE --mujoco STORE [--json F]
    .venv/bin/python -m lab.plant_compare robustness --rigid JSON ... --mujoco JSON ... [--json F]

``falls``: the measurement behind the MuJoCo plant's fall thresholds (``config/simulator.yaml``
``mujoco_fall_hip_height``, ``mujoco_fall_foot_tilt``): pushes of 25 ms at t = 0.2315 s, forward and backward,
modes both / tau / p, with only the body-contact fall active (the hip and foot checks set out of reach); per
run: outcome, the largest stance-foot pitch and the lowest hip, and when the pitch first passed 0.05 / 0.1 /
0.2 / 0.5 / 1 rad.

``cmap``: the capability-map slice side by side from two stores of ``scripts/capability_map`` (one per plant,
``--set plant=P --store STORE``): per cell (mode, direction, onset phase, duration), the survival boundary (the
largest simulated force below the lowest one that failed the survival rule, ``trial.survival``) and the no-fall
edge (the largest simulated force below the lowest one that fell), at the resolution of the simulated forces
(the map bisects both).

``robustness``: the max-push rows of ``scripts/robustness`` side by side from its summary JSONs (``--json``, one or
more per plant; a row found in several files is taken from the last): per perturbation and observer, the survival
boundary (largest survived force below the first failure, the first failure and its cause) and the no-fall
edge (largest force below the first fall, the first fall; "no fall to F" when the scan never fell), both
bisected to the same resolution. Survival is the studies' one rule (``trial.survival``).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from biped_sim.plant.config import load_sim_config
from biped_sim.plant.push import Push
from biped_controller.closed_loop import runner
from biped_controller.studies import provenance
from biped_controller.studies.plant_compare import _stance_pitch
from biped_controller.studies.trial.args import StudyArgumentParser


def falls_rows() -> list[dict]:
    scfg = load_sim_config(plant="mujoco", mujoco_fall_hip_height=1e-6, mujoco_fall_foot_tilt=100.0)
    out = []
    for mode in ("both", "tau", "p"):
        for f in (-1000, -800, -600, -500, 400, 500, 600, 700, 800):
            r = runner.run(steps=5, mode=mode, pushes=(Push(0.2315, 0.025, float(f)),), sim_config=scfg, max_time=3.5)
            pitch = np.abs(_stance_pitch(r.records))
            X = np.array([x.x for x in r.records])
            T = np.array([x.t for x in r.records])
            out.append(dict(mode=mode, force=f, walked=r.steps_walked, fall=r.fall_cause or None,
                            t_end=float(r.records[-1].t_end), max_pitch=float(pitch.max()), min_hip=float(X[:, 1].min()),
                            first_pitch={a: (float(T[np.argmax(pitch > a)]) if (pitch > a).any() else None)
                                         for a in (0.05, 0.1, 0.2, 0.5, 1.0)}))
            print(json.dumps(out[-1]), flush=True)
    return out


def robustness_table(rigid: list[Path], mujoco: list[Path]) -> tuple[str, dict]:
    """The side-by-side max-push rows (module docstring, ``robustness``)."""
    def rows(files):
        out = {}
        for f in files:
            for r in json.loads(Path(f).read_text(encoding="utf-8")).get("pushes", []):
                out[(r["level"], bool(r["observer"]), r["mode"])] = r
        return out
    R, M = rows(rigid), rows(mujoco)
    def strict(r):
        return f"{r['max_force']:g} ({r['first_failure']:g}, {r['cause']})" if r.get("first_failure") is not None \
            else f">= {r['max_force']:g}"
    def nofall(r):
        return (f"{r['max_force_no_fall']:g} ({r['first_fall']:g})" if r.get("first_fall") is not None
                else f"no fall to {r['max_force_no_fall']:g}")
    L = ["| perturbation | mode | observer | rigid: max push [N] (first failure) | rigid: no-fall edge [N] (first fall) | "
         "MuJoCo: max push [N] (first failure) | MuJoCo: no-fall edge [N] (first fall) |",
         "| --- | --- | --- | --- | --- | --- | --- |"]
    out = {}
    order = ("nominal", "torso mass +20 %", "inertias +30 %", "noise 1e-4 rad, 1e-2 rad/s", "delay 1 period",
             "delay 1 period, touchdown at once", "mu 0.5")
    rank = lambda lv: order.index(lv) if lv in order else len(order)   # noqa: E731
    for key in sorted(set(R) | set(M), key=lambda k: (not k[1], k[2], rank(k[0]), k[0])):
        r, m = R.get(key), M.get(key)
        cell = lambda x, f: f(x) if x is not None else "not run"   # noqa: E731
        L.append(f"| {key[0]} | {key[2]} | {'on' if key[1] else 'off'} | {cell(r, strict)} | {cell(r, nofall)} | "
                 f"{cell(m, strict)} | {cell(m, nofall)} |")
        out["/".join((key[0], key[2], "on" if key[1] else "off"))] = {
            p: (None if x is None else {k: x.get(k) for k in ("max_force", "first_failure", "cause", "max_force_no_fall",
                                                               "first_fall", "islands", "simulations")})
            for p, x in (("rigid", r), ("mujoco", m))}
    return "\n".join(L), out


def cell_edges(records: list[dict]) -> dict:
    """Per cell (mode, direction, phase, duration): strict boundary, no-fall edge, first fall cause, sims."""
    cells: dict = {}
    for r in records:
        cells.setdefault((r["mode"], r["direction"], r["phase"], r["duration"]), []).append(r)
    out = {}
    for key, rs in cells.items():
        rs = sorted(rs, key=lambda r: r["force"])
        strict = nofall = 0.0
        fall, cause = None, None
        for r in rs:
            if r["fall_time"] is not None:
                fall, cause = r["force"], r["cause"]
                break
            nofall = r["force"]
        for r in rs:
            if not r["survived"]:
                break
            strict = r["force"]
        # complete enough: the fall found and every coarse force below it simulated (an interrupted map, or two
        # workers running a cell's forces out of order, can leave a gap)
        from biped_controller.studies.capability_map import DEFAULT_COARSE, DEFAULT_MAX
        forces = {r["force"] for r in rs}
        gap = fall is None or any(DEFAULT_COARSE * k not in forces for k in range(1, int(fall // DEFAULT_COARSE)))
        # censored: every coarse force up to the scan's maximum simulated and none fell (no-fall edge >= it)
        censored = fall is None and all(DEFAULT_COARSE * k in forces
                                        for k in range(1, int(DEFAULT_MAX // DEFAULT_COARSE) + 1))
        out[key] = dict(strict=strict, no_fall=nofall, first_fall=None if gap else fall, cause=cause, sims=len(rs),
                        censored=censored)
    return out


def cmap_table(rigid: Path, mujoco: Path) -> tuple[str, dict]:
    load = lambda f: [json.loads(line) for line in f.read_text(encoding="utf-8").splitlines() if line.strip()]   # noqa: E731
    R, M = cell_edges(load(rigid)), cell_edges(load(mujoco))
    # a cell counts once both plants' scans reached a fall (its no-fall edge is known) or scanned every coarse force
    # without one (censored: the edge is at least the scan's maximum); an interrupted map leaves the rest out
    # (listed)
    done = lambda c: bool(c["first_fall"]) or c.get("censored", False)   # noqa: E731
    keys = sorted(k for k in set(R) & set(M) if done(R[k]) and done(M[k]))
    missing = sorted(k for k in set(R) | set(M) if k not in keys)
    L = ["| mode | direction | phase | rigid: survival [N] | rigid: no-fall edge [N] (first fall) | MuJoCo: survival [N] | "
         "MuJoCo: no-fall edge [N] (first fall) |", "| --- | --- | ---: | ---: | --- | ---: | --- |"]
    for k in keys:
        r, m = R[k], M[k]
        ff = lambda c: (f"{c['no_fall']:g} ({c['first_fall']:g} N {c['cause']})" if c["first_fall"]   # noqa: E731
                        else f">= {c['no_fall']:g} (no fall)")
        L.append(f"| {k[0]} | {k[1]} | {k[2]:g} | {r['strict']:g} | {ff(r)} | {m['strict']:g} | {ff(m)} |")
    groups = sorted({(k[0], k[1]) for k in keys})
    L += ["", "| mode | direction | cells | mean rigid survival [N] | mean rigid no-fall [N] | mean MuJoCo survival [N] | "
          "mean MuJoCo no-fall [N] | cells MuJoCo no-fall > rigid no-fall |", "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    summary = {}
    for g in groups:
        ks = [k for k in keys if (k[0], k[1]) == g]
        mean = lambda D, f: float(np.mean([D[k][f] for k in ks]))   # noqa: E731
        above = sum(1 for k in ks if M[k]["no_fall"] > R[k]["no_fall"])
        summary[f"{g[0]}/{g[1]}"] = dict(cells=len(ks), rigid_strict=mean(R, "strict"), rigid_no_fall=mean(R, "no_fall"),
                                         mujoco_strict=mean(M, "strict"), mujoco_no_fall=mean(M, "no_fall"), above=above)
        sm = summary[f"{g[0]}/{g[1]}"]
        L.append(f"| {g[0]} | {g[1]} | {len(ks)} | {sm['rigid_strict']:.1f} | {sm['rigid_no_fall']:.1f} | "
                 f"{sm['mujoco_strict']:.1f} | {sm['mujoco_no_fall']:.1f} | {above} of {len(ks)} |")
    if missing:
        L += ["", f"not complete on both plants ({len(missing)} cells): "
              + ", ".join(f"{k[0]} {k[1]} {k[2]:g}" for k in missing)]
    summary["missing"] = [list(k) for k in missing]
    return "\n".join(L), summary


def main(argv: list[str] | None = None) -> int:
    ap = StudyArgumentParser(prog="python -m lab.plant_compare", description=__doc__,
                             formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    fl = sub.add_parser("falls")
    fl.add_argument("--json", type=Path, default=None)
    cm = sub.add_parser("cmap")
    cm.add_argument("--rigid", type=Path, required=True)
    cm.add_argument("--mujoco", type=Path, required=True)
    cm.add_argument("--json", type=Path, default=None)
    rb = sub.add_parser("robustness")
    rb.add_argument("--rigid", type=Path, nargs="+", required=True)
    rb.add_argument("--mujoco", type=Path, nargs="+", required=True)
    rb.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    provenance.track(a.json, None, argv=argv, plant="rigid,mujoco")   # record of each file written (results/README.md)
    if a.cmd == "cmap":
        table, rows = cmap_table(a.rigid, a.mujoco)
        print(table)
    elif a.cmd == "robustness":
        table, rows = robustness_table(a.rigid, a.mujoco)
        print(table)
    else:
        rows = falls_rows()
        surv = [r for r in rows if r["fall"] is None]
        fell = [r for r in rows if r["fall"] is not None]
        print(f"survived {len(surv)}: largest stance-foot pitch {max(r['max_pitch'] for r in surv):.4f} rad, lowest hip "
              f"{min(r['min_hip'] for r in surv):.4f} m")
        print(f"fell {len(fell)}: causes {sorted(set(r['fall'] for r in fell))}; pitch 0.05 -> 1 rad within "
              f"{max(r['first_pitch'][1.0] - r['first_pitch'][0.05] for r in fell if r['first_pitch'][1.0]):.3f} s")
    if a.json is not None:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(rows, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
