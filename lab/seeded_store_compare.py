"""Do two runs of the capability map over seeds give the same answers, trial for trial? Compares the cells two
seeded-map stores (``scripts/capability_map --seeds N --store F``: one JSON line per finished cell, its key and
its result with every trial record) both hold under the same key, e.g. a run on Ray against a local run, or a
run on one code path against another.

    .venv/bin/python -m lab.seeded_store_compare A.jsonl B.jsonl [--label-a local] [--label-b ray] --json F

Per common cell and mode: the survival rates (force, survived, counted, excluded, rate, Wilson limits,
unpushed falls, faults), the crossings (bracket, estimate, interval, forces tried), the paired comparisons
(every force's pairs, counts, difference and Newcombe limits) and the trial records (sorted by force and seed
index; every field: verdict, reason, fall, steps, the parameter excursion to the last bit, seed), each compared
for exact equality; the JSON lists every difference (none when the runs agree) and the cells only one store
holds. Exit status 0 when every common cell is equal, 1 otherwise. Trials are matched on (force, seed index):
where the two searches took other paths, the trials only one ran are counted and the others compared.
``--tables``: A and B are two max-push tables over seeds (``scripts/experiment table --seeds N --json F``), one
cell each.

``--outcomes``: a run whose trials were ended by the early stop (``trial.stop.applies_mujoco_sensors``) against
the same cells' trials run in full. The cells are matched on their keys without ``early_stop``, and each trial
record is compared on its outcome only (:data:`OUTCOME`: verdict, reason, fall, whether it counts, seed); the
fields a stopped trial cannot share with the full one (the impacts walked, the parameter excursion up to the
stop, ``decided_at_step``) are left out. The rates, crossings and paired comparisons are compared whole.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

#: a mode's result fields compared (besides its trial records); the rest (settings, texts) describe the run
FIELDS = ("seeds", "seed_list", "levels", "resolution", "coarse_step", "scan_max", "rates", "crossings", "comparisons")


#: a trial record's outcome (``--outcomes``)
OUTCOME = ("force", "mode", "seed_index", "seed", "survived", "fell", "reason", "fall_cause", "fall_time", "counted",
           "unpushed_fall", "fault_kind")


def load(path: Path, drop: tuple[str, ...] = ()) -> dict[str, dict]:
    """The store's cells by their key (JSON, sorted keys, without the key's fields ``drop``); a later line of
    the same key replaces an earlier."""
    out = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.strip():
            rec = json.loads(line)
            out[json.dumps({k: v for k, v in rec["key"].items() if k not in drop}, sort_keys=True)] = rec
    return out


def _as_store(table: dict) -> dict[str, dict]:
    """A max-push table over seeds (``scripts/experiment table --seeds N --json F``) as a store of one cell: the
    paper's cell (its key: the table's settings and seed count)."""
    key = {"direction": "forward", "phase": None, "duration": None, "modes": sorted(table["modes"]),
           "seeds": table["seeds"]}
    return {json.dumps(key, sort_keys=True): {"key": key, "result": table["modes"]}}


def compare_cell(a: dict, b: dict, outcomes: bool = False) -> list[str]:
    """The differences between two results of one cell (every mode), as readable lines (``outcomes``: each
    trial on :data:`OUTCOME` only)."""
    diffs = []
    if sorted(a) != sorted(b):
        return [f"modes differ: {sorted(a)} against {sorted(b)}"]
    for mode in sorted(a):
        ra, rb = a[mode], b[mode]
        for f in FIELDS:
            if ra.get(f) != rb.get(f):
                diffs.append(f"{mode}: {f} differs")
        for ca, cb in zip(ra.get("crossings", []), rb.get("crossings", [])):
            if ca.get("estimate") != cb.get("estimate"):
                diffs.append(f"{mode}: crossing estimate at level {ca['level']:g}: {ca.get('estimate')} against "
                             f"{cb.get('estimate')}")
        ta = {(t["force"], t["seed_index"]): t for t in ra.get("trials", [])}
        tb = {(t["force"], t["seed_index"]): t for t in rb.get("trials", [])}
        if set(ta) != set(tb):      # another search path: the trials both ran are still compared
            diffs.append(f"{mode}: {len(set(ta) - set(tb))} trials only in a, {len(set(tb) - set(ta))} only in b")
        for k in sorted(set(ta) & set(tb)):
            x, y = ta[k], tb[k]
            if outcomes:
                x, y = {f: x.get(f) for f in OUTCOME}, {f: y.get(f) for f in OUTCOME}
            if x != y:
                keys = sorted(f for f in set(x) | set(y) if x.get(f) != y.get(f))
                diffs.append(f"{mode}: trial at {x['force']:g} N, seed index {x['seed_index']}: {', '.join(keys)}"
                             + (f" ({x['reason']!r} against {y['reason']!r})" if outcomes and "reason" in keys else ""))
    return diffs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("a", type=Path)
    ap.add_argument("b", type=Path)
    ap.add_argument("--label-a", default="a")
    ap.add_argument("--label-b", default="b")
    ap.add_argument("--outcomes", action="store_true",
                    help="keys without early_stop, trials on their outcome (a stopped run against a full one)")
    ap.add_argument("--tables", action="store_true",
                    help="A and B are two max-push tables over seeds (scripts/experiment table --seeds N --json F), "
                         "compared as one cell")
    ap.add_argument("--json", type=Path, required=True)
    args = ap.parse_args(argv)
    from biped_controller.studies import provenance
    provenance.track(args.json, argv=argv)
    drop = ("early_stop",) if args.outcomes else ()
    if args.tables:
        sa, sb = (_as_store(json.loads(p.read_text(encoding="utf-8"))) for p in (args.a, args.b))
    else:
        sa, sb = load(args.a, drop), load(args.b, drop)
    common = [k for k in sb if k in sa]
    cells = []
    for k in common:
        key = json.loads(k)
        d = compare_cell(sa[k]["result"], sb[k]["result"], args.outcomes)
        n = sum(len(r.get("trials", [])) for r in sb[k]["result"].values())
        stopped = {lab: sum(1 for r in s_[k]["result"].values() for t in r.get("trials", [])
                            if t.get("decided_at_step") is not None)
                   for lab, s_ in ((args.label_a, sa), (args.label_b, sb))}
        cells.append({"direction": key["direction"], "phase": key["phase"], "duration": key["duration"],
                      "modes": key["modes"], "seeds": key["seeds"], "trials": n, "equal": not d, "differences": d,
                      "stopped_early": stopped,
                      f"wall_time_{args.label_a}": sa[k].get("wall_time"),
                      f"wall_time_{args.label_b}": sb[k].get("wall_time")})
    only = lambda s, o: [json.loads(k) for k in s if k not in o]   # noqa: E731
    out = {"a": {"label": args.label_a, "store": str(args.a)}, "b": {"label": args.label_b, "store": str(args.b)},
           "compared": FIELDS + (("trial outcomes",) if args.outcomes else ("trials",)), "outcomes_only": args.outcomes,
           "cells": cells, "common_cells": len(cells),
           "equal_cells": sum(c["equal"] for c in cells), "trials_compared": sum(c["trials"] for c in cells),
           "trials_differing": sum(1 for c in cells for d in c["differences"] if ": trial at " in d),
           "crossing_estimates_differing": sum(1 for c in cells for d in c["differences"] if "crossing estimate" in d),
           "stopped_early": {lab: sum(c["stopped_early"][lab] for c in cells) for lab in (args.label_a, args.label_b)},
           "only_in_a": len(only(sa, sb)), "only_in_b": only(sb, sa)}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    for c in cells:
        where = "the table" if c["phase"] is None else f"{c['direction']} {c['phase']:g} {c['duration']:g} s"
        print(f"{where}: {c['trials']} trials, "
              + ("equal" if c["equal"] else f"{len(c['differences'])} differences: " + "; ".join(c["differences"][:5])))
    print(f"{out['equal_cells']} of {len(cells)} common cells equal ({out['trials_compared']} trials compared); "
          f"{out['only_in_a']} cells only in {args.label_a}, {len(out['only_in_b'])} only in {args.label_b}")
    return 0 if out["equal_cells"] == len(cells) else 1


if __name__ == "__main__":
    raise SystemExit(main())
