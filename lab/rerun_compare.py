"""Does a re-run of committed max-push results give the same answers? Compares result files of the working tree
(``scripts/experiment max-push --json F``, re-run with the commands in their ``provenance.json``) with the same
files at a git revision, mode by mode: the boundary, first failure and its cause, the no-fall edge and first fall,
the islands, the band, and every trial record (each field both records hold, exactly; the fields only the new
records hold, written by code newer than the old file, are listed as ``fields_added``).

    .venv/bin/python -m lab.rerun_compare --rev REV FILE.json ... --json F

The JSON lists, per file, those figures before and after, ``equal`` (every compared field and trial equal) and
the fields that differ. Exit status 0 when every file is equal, 1 otherwise.
"""
from __future__ import annotations

import argparse
import json
import subprocess
from pathlib import Path

#: a mode's fields compared besides its trial records (the settings and texts describe the run)
FIELDS = ("max_force", "first_failure", "failure_cause", "no_fall_edge", "first_fall", "fall_cause", "islands",
          "no_fall_islands", "band", "resolution", "coarse_step", "scan_max")


def at_revision(rev: str, path: Path) -> dict:
    """The file ``path`` (relative to the repository) as committed at ``rev``."""
    text = subprocess.run(["git", "show", f"{rev}:{path.as_posix()}"], capture_output=True, text=True,
                          check=True).stdout
    return json.loads(text)


def compare(old: dict, new: dict) -> dict:
    """Per mode: the headline figures before and after and the fields (or trials) that differ."""
    out = {}
    for mode in sorted(set(old["modes"]) | set(new["modes"])):
        a, b = old["modes"].get(mode), new["modes"].get(mode)
        if a is None or b is None:
            out[mode] = {"equal": False, "differences": ["mode in one file only"]}
            continue
        diffs = [f for f in FIELDS if a.get(f) != b.get(f)]
        ta, tb = a.get("trials", []), b.get("trials", [])
        added = sorted({k for x, y in zip(ta, tb) for k in set(y) - set(x)})
        if len(ta) != len(tb):
            diffs.append(f"{len(ta)} trials against {len(tb)}")
        else:
            for x, y in zip(ta, tb):
                keys = sorted(k for k in set(x) & set(y) if x[k] != y[k])
                if keys:
                    diffs.append(f"trial at {x.get('force')} N: " + ", ".join(keys))
        out[mode] = {"fields_added": added, "before": {f: a.get(f) for f in ("max_force", "first_failure", "failure_cause", "no_fall_edge")},
                     "after": {f: b.get(f) for f in ("max_force", "first_failure", "failure_cause", "no_fall_edge")},
                     "trials": len(tb), "equal": not diffs, "differences": diffs}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", type=Path, nargs="+")
    ap.add_argument("--rev", required=True, help="the git revision holding the earlier files")
    ap.add_argument("--json", type=Path, required=True)
    args = ap.parse_args(argv)
    from biped_controller.studies import provenance
    provenance.track(args.json, argv=argv)
    rows = {}
    for f in args.files:
        rows[f.as_posix()] = compare(at_revision(args.rev, f), json.loads(f.read_text(encoding="utf-8")))
    out = {"revision": args.rev, "files": rows,
           "equal_files": sum(all(m["equal"] for m in r.values()) for r in rows.values()), "count": len(rows)}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    for f, r in rows.items():
        for mode, m in r.items():
            print(f"{f} {mode}: " + ("equal" if m["equal"] else "differs: " + "; ".join(m["differences"][:4]))
                  + f" ({m.get('before', {}).get('max_force')} -> {m.get('after', {}).get('max_force')} N)")
    print(f"{out['equal_files']} of {out['count']} files equal")
    return 0 if out["equal_files"] == out["count"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
