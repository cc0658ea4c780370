"""The test suite's wall time as CI runs it: a fresh clone of this checkout's HEAD, ``CI=true bash .ci/run``.

    .venv/bin/python -m benchmarks.suite_time [--workers N ...] [--out results/suite_time/results.json]

For each ``--workers`` value (``BIPED_TEST_WORKERS``: 2 is ``scripts/test``'s default, 0 runs pytest in one
process) the clone is made anew in a temporary directory (its own ``.venv``: the setup is part of the run, as
on a CI machine), ``.ci/run`` is run with ``CI=true``, and the record keeps: the exit code, the whole run's wall
time [s], pytest's own time from its closing line [s], the counts of that line (passed, failed, skipped, ...),
and the 1-minute load average before and after. The issue's limit (530 s of pytest at load below 1) is printed
beside the figures, never asserted. The runs are sequential: a second run never shares the cores with a first.
Writes the JSON with its provenance record (results/README.md).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LIMIT_S = 530.0
#: pytest's closing line, e.g. "==== 1458 passed, 2 skipped, 49 warnings in 340.18s (0:05:40) ===="
CLOSING = re.compile(r"=+ (?P<counts>.+?) in (?P<secs>[0-9.]+)s(?: \([0-9:]+\))? =+\s*$")


def parse_closing(text: str) -> dict | None:
    """The counts and seconds of pytest's last closing line in ``text`` (None when there is none)."""
    found = None
    for line in text.splitlines():
        m = CLOSING.search(line)
        if m:
            found = m
    if found is None:
        return None
    counts = {}
    for part in found.group("counts").split(","):
        n, _, what = part.strip().partition(" ")
        if n.isdigit():
            counts[what] = int(n)
    return {"counts": counts, "pytest_s": float(found.group("secs"))}


def one_run(workers: int, log_dir: Path) -> dict:
    """One fresh clone of HEAD and its ``.ci/run`` with ``BIPED_TEST_WORKERS=workers``."""
    with tempfile.TemporaryDirectory(prefix="suite_time_") as tmp:
        clone = Path(tmp) / "clone"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        env = {k: v for k, v in os.environ.items() if not k.startswith(("VIRTUAL_ENV", "BIPED_"))}
        env.update(CI="true", BIPED_TEST_WORKERS=str(workers))
        load0 = os.getloadavg()[0]
        t0 = time.perf_counter()
        p = subprocess.run(["bash", ".ci/run"], cwd=clone, env=env, stdin=subprocess.DEVNULL,
                           capture_output=True, text=True)
        wall = time.perf_counter() - t0
        log = log_dir / f"workers_{workers}.log"
        log.write_text(p.stdout + p.stderr, encoding="utf-8")
    rec = {"workers": workers, "exit_code": p.returncode, "wall_s": round(wall, 1),
           "loadavg_1min_before": round(load0, 2), "loadavg_1min_after": round(os.getloadavg()[0], 2)}
    rec.update(parse_closing(p.stdout) or {"counts": None, "pytest_s": None})
    return rec


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, nargs="+", default=[2],
                    help="BIPED_TEST_WORKERS values, one fresh-clone run each (default: 2)")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "suite_time" / "results.json")
    a = ap.parse_args(argv)
    if any(w < 0 for w in a.workers):
        ap.error("--workers: worker counts are whole numbers >= 0")
    from biped_controller.studies.provenance import Run
    prov = Run()
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="suite_time_logs_") as logs:
        runs = [one_run(w, Path(logs)) for w in a.workers]
    out = {"meta": {"date": time.strftime("%Y-%m-%d %H:%M:%S"), "cpus": os.cpu_count(), "head": head},
           "limit_pytest_s": LIMIT_S, "runs": runs}
    a.out.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    prov.record(a.out)
    for r in runs:
        print(f"workers {r['workers']}: exit {r['exit_code']}, pytest {r['pytest_s']} s (limit {LIMIT_S:g} s), "
              f"whole .ci/run {r['wall_s']} s, load {r['loadavg_1min_before']} -> {r['loadavg_1min_after']}, "
              f"{r['counts']}")
    return 0 if all(r["exit_code"] == 0 for r in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
