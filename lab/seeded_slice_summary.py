"""Which controller holds more over a probabilistic slice? Reads a seeded map's summary (``scripts/capability_map
--seeds N --json F``, two modes on common seeds) and, per direction and duration, counts the onsets where one mode's
crossing lies above the other's and where one is ahead beyond the paired interval (some force tried with
Newcombe's interval of the difference of the survival rates wholly above 0, or wholly below), with the means of
the crossings: the figures the report states, in a file its markers read.

    .venv/bin/python -m lab.seeded_slice_summary SLICE.json --json F

Per (direction, duration): ``phases``; per level the mean crossing of each mode and the onsets where a's crossing
is above, equal to, below b's (``a`` the first mode of the comparison, ``b`` the second); ``a_ahead`` /
``b_ahead`` the onsets where that mode is ahead beyond the paired interval at some force (an onset may be in
both: at different forces); the seeds counted apart (unpushed falls, faults) over every rate.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path


def summarise(result: dict) -> list[dict]:
    """The per-(direction, duration) summaries of a seeded map's result (module docstring)."""
    groups: dict[tuple, list[dict]] = {}
    for c in result["cells"]:
        groups.setdefault((c["direction"], c["duration"]), []).append(c)
    out = []
    for (direction, duration), cells in groups.items():
        cells = sorted(cells, key=lambda c: c["phase"])
        comp = cells[0]["comparisons"][0]
        a, b = comp["a"], comp["b"]
        row = {"direction": direction, "duration": duration, "a": a, "b": b, "onsets": len(cells),
               "phases": [c["phase"] for c in cells], "levels": []}
        for i, level in enumerate(result["levels"]):
            est = {m: [c["modes"][m]["crossings"][i]["estimate"] for c in cells] for m in (a, b)}
            both_known = [(x, y, c["phase"]) for x, y, c in zip(est[a], est[b], cells) if x is not None and y is not None]
            row["levels"].append({
                "level": level,
                "mean": {m: (sum(v for v in est[m] if v is not None) / sum(v is not None for v in est[m])
                             if any(v is not None for v in est[m]) else None) for m in (a, b)},
                "a_above": [p for x, y, p in both_known if x > y],
                "equal": [p for x, y, p in both_known if x == y],
                "b_above": [p for x, y, p in both_known if x < y],
            })
            row["levels"][-1].update({f"{k}_count": len(row["levels"][-1][k]) for k in ("a_above", "equal", "b_above")})
        a_ahead, b_ahead = [], []
        for c in cells:
            forces = next(x for x in c["comparisons"] if x["a"] == a and x["b"] == b)["forces"]
            if any(f["lo"] is not None and f["lo"] > 0 for f in forces):
                a_ahead.append(c["phase"])
            if any(f["hi"] is not None and f["hi"] < 0 for f in forces):
                b_ahead.append(c["phase"])
        row.update(a_ahead=a_ahead, b_ahead=b_ahead, a_ahead_count=len(a_ahead), b_ahead_count=len(b_ahead),
                   counted_apart=sum(r["excluded"] for c in cells for m in c["modes"].values() for r in m["rates"]),
                   trials=sum(c["trials"] for c in cells))
        out.append(row)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("slice", type=Path)
    ap.add_argument("--json", type=Path, required=True)
    args = ap.parse_args(argv)
    from biped_controller.studies import provenance
    provenance.track(args.json, argv=argv)
    result = json.loads(args.slice.read_text(encoding="utf-8"))
    out = {"source": str(args.slice), "groups": summarise(result)}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    for g in out["groups"]:
        print(f"{g['direction']} {g['duration']:g} s, {g['onsets']} onsets, {g['a']} against {g['b']}:")
        for lv in g["levels"]:
            print(f"  {100 * lv['level']:g} %: means {g['a']} {lv['mean'][g['a']]:.1f} N, {g['b']} {lv['mean'][g['b']]:.1f} N; "
                  f"{g['a']} above at {lv['a_above_count']}, equal at {lv['equal_count']}, {g['b']} above at "
                  f"{lv['b_above_count']} ({lv['b_above']})")
        print(f"  ahead beyond the paired interval: {g['a']} at {g['a_ahead_count']} {g['a_ahead']}, {g['b']} at "
              f"{g['b_ahead_count']} {g['b_ahead']}; counted apart {g['counted_apart']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
