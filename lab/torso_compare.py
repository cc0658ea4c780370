"""The torso parameter's capability map read back: its modes against a base per duration and direction
(docs/torso_parameter.md; moved out of ``biped_controller.studies.torso``, once its ``compare``). Run from the
repository root::

    .venv/bin/python -m lab.torso_compare SUMMARY.json [--base both] [--modes lambda,all] [--json FILE]

A capability map's summary (``scripts/capability_map --json``) read back: per duration and
direction, each mode's boundary [N] per onset phase (markdown table), its mean over the phases, the ratio
of means mode / base, the phases where the mode's boundary is higher, equal or lower than the base's, and
the cell of largest ratio. Cells missing in either mode are left out of both means (named in the output).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from biped_controller.studies import provenance
from biped_controller.studies.trial.args import StudyArgumentParser, add_modes_arg


def map_comparison(boundaries: list[dict], base: str = "both", modes: tuple[str, ...] = ("lambda", "all")) -> dict:
    """From a capability map's ``boundaries`` (dicts with mode, direction, duration, phase, force [N], censored):
    for each (duration, direction), per mode the boundary per phase, the mean over the phases both the mode
    and ``base`` have, the ratio mean / base mean, the phases where the mode is higher / equal / lower than
    ``base`` and the cell of largest ratio. Returns {"groups": [...]} (JSON-ready)."""
    cells: dict = {}
    for b in boundaries:
        cells[(b["mode"], b["direction"], float(b["duration"]), round(float(b["phase"]), 9))] = b
    groups = []
    keys = sorted({(k[2], k[1]) for k in cells if k[0] == base}, key=lambda k: (k[0], k[1] != "forward"))
    for dur, direction in keys:
        phases = sorted(k[3] for k in cells if k[0] == base and k[1] == direction and k[2] == dur)
        g = {"duration": dur, "direction": direction, "phases": phases, "modes": {}}
        for m in (base,) + tuple(modes):
            g["modes"][m] = {"force": [cells[(m, direction, dur, ph)]["force"] if (m, direction, dur, ph) in cells else None
                                       for ph in phases],
                             "censored": [bool(cells[(m, direction, dur, ph)].get("censored", False))
                                          if (m, direction, dur, ph) in cells else None for ph in phases]}
        fb = g["modes"][base]["force"]
        for m in (base,) + tuple(modes):
            fm = g["modes"][m]["force"]
            both_there = [i for i in range(len(phases)) if fm[i] is not None and fb[i] is not None]
            d = g["modes"][m]
            d["missing_phases"] = [phases[i] for i in range(len(phases)) if i not in both_there]
            if not both_there:
                d.update(mean=None, base_mean=None, ratio=None, higher=[], equal=[], lower=[], best=None)
                continue
            mean = sum(fm[i] for i in both_there) / len(both_there)
            bmean = sum(fb[i] for i in both_there) / len(both_there)
            ratios = [(fm[i] / fb[i] if fb[i] > 0 else math.inf, phases[i]) for i in both_there]
            best = max(ratios)
            d.update(mean=mean, base_mean=bmean, ratio=mean / bmean if bmean > 0 else math.inf,
                     higher=[phases[i] for i in both_there if fm[i] > fb[i]],
                     equal=[phases[i] for i in both_there if fm[i] == fb[i]],
                     lower=[phases[i] for i in both_there if fm[i] < fb[i]],
                     best={"phase": best[1], "ratio": best[0]})
        groups.append(g)
    return {"base": base, "modes": list(modes), "groups": groups}


def _print_comparison(cmp: dict) -> None:
    fmt = lambda v: "-" if v is None else f"{v:.2f}"   # noqa: E731
    for g in cmp["groups"]:
        print(f"\n### {g['direction']}, {g['duration']:g} s\n")
        print("| mode | " + " | ".join(f"{p:g}" for p in g["phases"]) + " | mean |")
        print("| --- |" + " ---: |" * (len(g["phases"]) + 1))
        for m, d in g["modes"].items():
            vals = [fmt(v) + ("+" if c else "") for v, c in zip(d["force"], d["censored"])]
            print(f"| {m} | " + " | ".join(vals) + f" | {fmt(d['mean'])} |")
        for m in cmp["modes"]:
            d = g["modes"][m]
            if d["mean"] is None:
                continue
            print(f"\n{m} / {cmp['base']}: mean {d['mean']:.1f} vs {d['base_mean']:.1f} N = {d['ratio']:.3f}x; "
                  f"higher at {len(d['higher'])} phases {d['higher']}, equal at {len(d['equal'])} {d['equal']}, "
                  f"lower at {len(d['lower'])} {d['lower']}; best cell {d['best']['ratio']:.2f}x at phase "
                  f"{d['best']['phase']:g}" + (f"; missing {d['missing_phases']}" if d["missing_phases"] else ""))


def main(argv=None) -> int:
    ap = StudyArgumentParser(prog="python -m lab.torso_compare", description=__doc__,
                             formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("summary", type=Path, help="a capability map's summary JSON")
    ap.add_argument("--base", default="both")
    add_modes_arg(ap, ("lambda", "all"), "lambda,all", controller=False)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    provenance.track(args.json, args=args, argv=argv)   # record of each file written (results/README.md)
    try:
        summary = json.loads(args.summary.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        ap.error(f"summary: cannot read {args.summary}: {exc}")
    if "boundaries" not in summary:
        ap.error(f"summary: {args.summary} has no 'boundaries' (not a capability map summary)")
    res = map_comparison(summary["boundaries"], args.base, tuple(args.modes))
    _print_comparison(res)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
