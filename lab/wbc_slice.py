"""The whole-body baseline's 25 ms capability-map slice: modes none, wbc, both and hybrid per (direction,
onset phase), and the goal check hybrid >= max(both, wbc) cell by cell (docs/baseline_wbc.md; moved out of
``biped_controller.studies.baseline_wbc``, once its ``--slice-map``). Run from the repository root::

    .venv/bin/python -m lab.wbc_slice SUMMARY [SUMMARY ...] [--json F] [--figure F]

reads ``scripts/capability_map --json`` summaries of one plant, on their boundaries (the largest survived force
[N] below the lowest failing one, bisected, under the one survival rule); the summaries' cells are merged, so
one map per mode will do, and a cell given twice is an error naming it. Prints the slice (Markdown rows, mean
per mode and direction), the goal check and the first failure causes; ``--json``: the same as JSON under the
plant's name; ``--figure``: a PNG of the edges by phase.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from biped_controller.studies import provenance
from biped_controller.studies.trial.runs import DEFAULT_DURATION


SLICE_MODES = ("none", "wbc", "both", "hybrid")


def map_slice(summaries: list[tuple[str, dict]]) -> dict:
    """{(mode, direction, phase): {force, cause, fall_time, islands}} from capability-map summaries (their 0.025 s
    boundaries), given as (name, summary) pairs. Raises ValueError naming the summary and the cell when a
    cell comes twice, or when the summaries are of different plants (``settings.differs.plant``, rigid when
    absent)."""
    plants = {name: summary_plant(s) for name, s in summaries}
    if len(set(plants.values())) > 1:
        raise ValueError("the summaries are of different plants: "
                         + ", ".join(f"{n} ({p})" for n, p in plants.items()))
    cells: dict = {}
    for name, summary in summaries:
        for b in summary["boundaries"]:
            if abs(float(b["duration"]) - DEFAULT_DURATION) > 1e-12:
                continue
            key = (b["mode"], b["direction"], float(b["phase"]))
            if key in cells:
                raise ValueError(f"{name} gives the cell {key[0]} {key[1]} phase {key[2]:g} a second time")
            cells[key] = {"force": float(b["force"]), "cause": b["cause"], "fall_time": b["fall_time"],
                          "islands": b["island_ranges"]}
    return cells


def summary_plant(summary: dict) -> str:
    """The plant a capability-map summary was measured on (its settings' differences; rigid, the default,
    when they name none)."""
    return str(((summary.get("settings") or {}).get("differs") or {}).get("plant", "rigid"))


def slice_report(cells: dict, title: str) -> tuple[list[str], dict]:
    """Markdown rows (mode x direction over the onset phases, means) and the goal check per cell:
    hybrid >= max(both, wbc) where the three are known."""
    phases = sorted({k[2] for k in cells})
    L = [f"### {title}", "", "| mode | dir | " + " | ".join(f"{p:g}" for p in phases) + " | mean |",
         "| --- | --- | " + " | ".join("---:" for _ in phases) + " | ---: |"]
    for d in ("forward", "backward"):
        for m in SLICE_MODES:
            vals = [cells.get((m, d, p), {}).get("force") for p in phases]
            if all(v is None for v in vals):
                continue
            known = [v for v in vals if v is not None]
            L.append(f"| {m} | {d[:4]} | " + " | ".join("-" if v is None else f"{v:g}" for v in vals)
                     + f" | {np.mean(known):.1f} ({len(known)}) |")
    goal = {"met": [], "missed": [], "unknown": []}
    for d in ("forward", "backward"):
        for p in phases:
            v = {m: cells.get((m, d, p), {}).get("force") for m in ("wbc", "both", "hybrid")}
            if any(x is None for x in v.values()):
                goal["unknown"].append([d, p])
            elif v["hybrid"] >= max(v["both"], v["wbc"]):
                goal["met"].append([d, p])
            else:
                goal["missed"].append([d, p, v])
    L += ["", f"goal hybrid >= max(both, wbc): met in {len(goal['met'])} cells, missed in {len(goal['missed'])}"
          + "".join(f"; missed {g[0]} {g[1]:g}: " + ", ".join(f"{k} {x:g}" for k, x in g[2].items())
                    for g in goal["missed"])
          + f"; not measured for all three: {len(goal['unknown'])}"]
    causes: dict = {}
    for (m, d, p), c in cells.items():
        if c.get("cause"):
            causes.setdefault(m, {}).setdefault(c["cause"], 0)
            causes[m][c["cause"]] += 1
    L.append("first failure causes: " + "; ".join(f"{m} " + ", ".join(f"{k} {n}" for k, n in sorted(cs.items()))
                                                  for m, cs in sorted(causes.items())))
    return L, {"goal": goal, "causes": causes,
               "cells": {f"{k[0]}/{k[1]}/{k[2]:g}": v for k, v in sorted(cells.items())}}


def slice_figure(cells: dict, title: str, path: Path) -> None:
    """Edge [N] against onset phase, one line per mode, forward and backward side by side (a missing cell
    is a gap in its line)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    phases = sorted({k[2] for k in cells})
    fig, ax = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for a, d in zip(ax, ("forward", "backward")):
        for m in SLICE_MODES:
            v = [cells.get((m, d, p), {}).get("force") for p in phases]
            if any(x is not None for x in v):
                a.plot(phases, [np.nan if x is None else x for x in v], "o-", ms=3, label=m)
        a.set_title(f"{d}, 25 ms")
        a.set_xlabel("onset phase of the first step")
        a.grid(alpha=0.3)
    ax[0].set_ylabel("boundary [N]")
    ax[0].legend(fontsize=8)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m lab.wbc_slice", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("summaries", type=Path, nargs="+", metavar="SUMMARY",
                    help="capability-map summary JSON(s) of one plant")
    ap.add_argument("--json", type=Path, default=None, help="the slice as JSON")
    ap.add_argument("--figure", type=Path, default=None, help="PNG of the edges by phase")
    args = ap.parse_args(argv)
    summaries = [(str(p), json.loads(p.read_text())) for p in args.summaries]
    try:
        cells = map_slice(summaries)
    except ValueError as e:
        print(e, file=sys.stderr)
        return 2
    plant = summary_plant(summaries[0][1])
    provenance.track(args.json, args.figure, argv=argv, plant=plant)   # record of each file written (results/README.md)
    names = ", ".join(n for n, _ in summaries)
    L, out = slice_report(cells, f"{plant} plant: boundary [N] ({names})")
    if args.figure is not None:
        slice_figure(cells, f"{plant} plant: boundary", args.figure)
    print("\n".join(L))
    if args.json is not None:
        args.json.write_text(json.dumps({plant: out}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
