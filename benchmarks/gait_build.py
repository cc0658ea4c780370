"""Gait family built from nothing: today's generator beside the fast build, in one run.

    .venv/bin/python -m benchmarks.gait_build [--quick] [--out results/gait_build] [--repeats 2] [--skip-old]

Each build runs in a fresh process (``python -m ...``), from the robot's description and gait settings
alone (no committed family read, no warm start), with an empty ``NUMBA_CACHE_DIR`` and its own temporary
output directory; the machine's load average is sampled before and after each, its wall time and CPU time
(``cpu_s``: user + system of the build and of the worker processes it waited for) recorded. Rows:

* ``old``: ``biped_controller.gaits.generation`` as today (``scripts/generate_gait_family`` without
  ``--check``), BLAS threads left at their default;
* ``new``: ``biped_controller.gaits.build`` (2 worker processes, single-threaded BLAS, fast evaluator),
  ``--repeats`` times: the files of the repeats are compared byte for byte (sha256);
* ``today`` (``--today``): the same build with ``--no-memo`` (every solve of the continuation sweeps run again,
  the build as it was before ``SolveMemo``), alternating with the ``new`` runs (today_1, new_1, today_2, ...):
  its file must be the new one byte for byte (``summary.new_identical_to_today``). With ``--today-rev REV`` the
  today rows run the build of commit REV instead (``git archive REV src/``, its packages first on
  ``PYTHONPATH``, ``BIPED_ROOT`` this tree; each row records the module file it ran, ``module_file``).

For each family: the wall time, the validation figures the generator stores (fit errors at the fitted and
held-out strides, the fitted family's smallest true margin, clearance and largest periodicity residual
between the strides, the valid range) and its distance to the committed family
(``robots/biped7/gait_family.json``) over the committed range: largest |q - q_committed| [rad] and
|dq/dtau - ...| [rad/s] on a 61 x 41 (p, t) grid, largest difference of the stride coefficients c.
Writes ``results.json`` and ``results.md`` in ``--out`` with their provenance records. The 60 s target is
printed beside the figures, never asserted. ``--quick``: a reduced family (6 strides, 2 smoothing passes).

``--blas-probe``: the reproducibility probe instead (``blas_configs.json``): three held-out strides of the
committed family re-solved from their own targets under 1 and 2 OpenBLAS threads and two OpenBLAS kernels.

Hook into ``scripts/bench``: run ``python -m benchmarks.gait_build`` as its own step (about 10-20 min at
load 3-6: today's generator dominates); its stable figures are ``summary.new_wall_s``,
``summary.old_wall_s``, ``summary.ratio_old_over_new`` and ``summary.new_identical_across_runs`` of
``results/gait_build/results.json``.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 60.0


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _run(cmd: list[str], env_extra: dict, log: Path) -> dict:
    env = dict(os.environ)
    env.update(env_extra)
    load0 = os.getloadavg()
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    with open(log, "w", encoding="utf-8") as fh:
        proc = subprocess.run(cmd, cwd=ROOT, env=env, stdout=fh, stderr=subprocess.STDOUT)
    wall = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    # CPU of the build and of the worker processes it waited for (user + system) [s]
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    return {"command": " ".join(cmd[1:]), "wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "exit": proc.returncode,
            "load_before": [round(x, 2) for x in load0], "load_after": [round(x, 2) for x in os.getloadavg()],
            "env": env_extra}


def _archive(rev: str, dest: Path) -> dict:
    """Commit ``rev``'s ``src/`` unpacked under ``dest``; the environment that runs its packages (first on
    ``PYTHONPATH``) with this tree's configuration and robots (``BIPED_ROOT``)."""
    dest.mkdir(parents=True)
    arc = subprocess.run(["git", "archive", rev, "src/"], cwd=ROOT, capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=arc, check=True)
    pkgs = [str(p) for p in sorted((dest / "src").iterdir()) if (p / p.name / "__init__.py").is_file()]
    return {"PYTHONPATH": os.pathsep.join(pkgs), "BIPED_ROOT": str(ROOT), "TODAY_REV": rev}


def _module_file(env_extra: dict) -> str:
    """The file ``biped_controller.gaits.build`` is imported from under ``env_extra`` (which code a row ran)."""
    env = dict(os.environ)
    env.update({k: v for k, v in env_extra.items() if k != "NUMBA_CACHE_DIR"})
    proc = subprocess.run([sys.executable, "-c", "import biped_controller.gaits.build as b; print(b.__file__)"],
                          cwd=ROOT, env=env, capture_output=True, text=True)
    return proc.stdout.strip() or proc.stderr.strip()[-300:]


def _distance(path: Path, ref_path: Path) -> dict:
    """Distance of the family in ``path`` to the one in ``ref_path`` over the reference's range."""
    from biped_model.gait_family import GaitFamily
    fam, ref = GaitFamily.load(path), GaitFamily.load(ref_path)
    lo, hi = max(fam.p_min, ref.p_min), min(fam.p_max, ref.p_max)
    dq = dv = 0.0
    for p in np.linspace(lo, hi, 61):
        for t in np.linspace(0.0, ref.T, 41):
            a, b = fam.evaluate(p, t), ref.evaluate(p, t)
            dq = max(dq, float(np.max(np.abs(a.q - b.q))))
            dv = max(dv, float(np.max(np.abs(a.dq_dtau - b.dq_dtau))))
    d, r = json.loads(path.read_text()), json.loads(ref_path.read_text())
    rs = {x["stride"]: np.array(x["c"]) for x in r["strides"]}
    dc = [float(np.max(np.abs(np.array(x["c"]) - rs[x["stride"]]))) for x in d["strides"] if x["stride"] in rs]
    return {"compared_range": [lo, hi], "max_abs_dq": dq, "max_abs_dqdot": dv,
            "max_abs_dc_strides": max(dc) if dc else None}


def _figures(path: Path) -> dict:
    d = json.loads(path.read_text())
    v = d["validation"]
    keys = ("fit_error_q_max", "fit_error_qdot_max", "held_out_fit_error_q_max", "held_out_fit_error_qdot_max",
            "held_out_all_feasible", "fitted_min_margin", "fitted_min_clearance", "fitted_max_periodicity_residual",
            "max_abs_dq_dp", "max_abs_d2q_dp2")
    out = {k: v.get(k) for k in keys}
    out["range"] = [d["family"]["p_min"], d["family"]["p_max"]]
    out["strides_feasible"] = sum(bool(r["success"]) for r in d["strides"])
    out["strides"] = len(d["strides"])
    out["strides_min_margin"] = min(r["min_margin"] for r in d["strides"])
    out["strides_max_periodicity_residual"] = max(r["periodicity_residual"] for r in d["strides"])
    out["held_out_min_margin"] = min((r["min_margin"] for r in d.get("held_out", [])), default=None)
    out["held_out_max_periodicity_residual"] = max((r["periodicity_residual"] for r in d.get("held_out", [])), default=None)
    out["criterion_p_d"] = next(r["criterion"] for r in d["strides"] if r["stride"] == d["family"]["p_d"])
    sp = d.get("speed_1mps")
    out["speed_best_stride_parabolic"] = sp.get("best_stride_parabolic") if sp else None
    return out


#: BLAS configurations of the reproducibility probe: thread count and OpenBLAS kernel (core type).
BLAS_CONFIGS = ({"OPENBLAS_NUM_THREADS": "1"}, {"OPENBLAS_NUM_THREADS": "2"},
                {"OPENBLAS_NUM_THREADS": "1", "OPENBLAS_CORETYPE": "Haswell"},
                {"OPENBLAS_NUM_THREADS": "2", "OPENBLAS_CORETYPE": "Haswell"})
PROBE_HELD_OUT = (3, 12, 20)

_PROBE = """
import json, sys
import numpy as np
from biped_model.settings import default_robot_dir
from biped_controller.gaits.blas import blas_info
from biped_controller.gaits.generation import fit_strides
from biped_controller.gaits.optimizer import StepOptimizer, load_gait_settings
data = json.loads((default_robot_dir() / "gait_family.json").read_text())
st = load_gait_settings()
recs = data["strides"]
fam = fit_strides([r["stride"] for r in recs], np.array([r["a"] for r in recs]), st)
opt = StepOptimizer(settings=st)
scale = fam.T ** np.arange(5)[None, :]
out = []
for i in json.loads(sys.argv[1]):
    h = data["held_out"][i]
    tg = fam.coefficients(h["stride"])[0] * scale
    sol = opt.solve(h["stride"], c0=tg, target=tg, weight=h["smoothing_weight"], diagnose=False)
    out.append({"held_out": i, "stride": h["stride"], "iterations": sol.iterations,
                "iterations_committed": h["iterations"], "c": sol.c.tolist(),
                "max_abs_dc_committed": float(np.max(np.abs(sol.c - np.array(h["c"]))))})
print(json.dumps({"blas": blas_info(), "solves": out}))
"""


def blas_probe(out_dir: Path) -> Path:
    """One SLSQP solve per held-out stride of :data:`PROBE_HELD_OUT`, from the committed family's own
    target (the fit through its stored strides, as ``generate`` computed it), under each configuration
    of :data:`BLAS_CONFIGS` in a fresh process: the solutions against each other and against the committed
    held-out records (``blas_configs.json``)."""
    from biped_controller.studies import provenance
    run = provenance.Run()
    rows = []
    for cfg in BLAS_CONFIGS:
        env = dict(os.environ)
        env.pop("OPENBLAS_CORETYPE", None)
        env.update(cfg)
        proc = subprocess.run([sys.executable, "-c", _PROBE, json.dumps(list(PROBE_HELD_OUT))], cwd=ROOT, env=env,
                              capture_output=True, text=True)
        r = json.loads(proc.stdout.strip().splitlines()[-1]) if proc.returncode == 0 else {"error": proc.stderr[-2000:]}
        r["env"] = cfg
        rows.append(r)
        print(cfg, [(s["iterations"], s["iterations_committed"], f"{s['max_abs_dc_committed']:.1e}")
                    for s in r.get("solves", [])], flush=True)
    pair = {}
    for i, a in enumerate(rows):
        for j, b in enumerate(rows):
            if j > i and "solves" in a and "solves" in b:
                pair[f"{i}-{j}"] = max(float(np.max(np.abs(np.array(x["c"]) - np.array(y["c"]))))
                                       for x, y in zip(a["solves"], b["solves"]))
    res = {"configs": rows, "max_abs_dc_between_configs": pair,
           "note": "configs indexed as listed; 'c' are the solutions' normalised coefficients"}
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "blas_configs.json"
    path.write_text(json.dumps(res, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    run.record(path)
    return path


def main(argv: list[str] | None = None) -> int:
    from biped_controller.studies import provenance
    from biped_controller.gaits.blas import blas_info
    from biped_controller.gaits.build import REDUCED, write_settings
    from biped_controller.gaits.optimizer import load_gait_settings
    from biped_controller.gaits.generation import within_tolerance
    from biped_model.settings import default_robot_dir

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "gait_build")
    ap.add_argument("--quick", action="store_true", help="reduced family (6 strides, 2 smoothing passes)")
    ap.add_argument("--repeats", type=int, default=2, help="runs of the new build (compared byte for byte)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--skip-old", action="store_true", help="only the new build")
    ap.add_argument("--today", action="store_true",
                    help="also the build without its solve memo (gaits.build --no-memo), alternating with the new runs")
    ap.add_argument("--today-rev", default=None, metavar="REV",
                    help="with --today: the today rows run commit REV's build (git archive of its src/) instead")
    ap.add_argument("--old-single-thread", action="store_true",
                    help="also today's generator with OPENBLAS_NUM_THREADS=1 (row old_blas1): the share of the BLAS threads")
    ap.add_argument("--keep", type=Path, default=None, help="copy the built families into this directory")
    ap.add_argument("--tag", default=None, help="write results_TAG.json / .md (keeps the main results)")
    ap.add_argument("--blas-probe", action="store_true",
                    help="only the reproducibility probe: held-out solves under 4 BLAS configurations (blas_configs.json)")
    args = ap.parse_args(argv)
    if args.blas_probe:
        print(blas_probe(args.out))
        return 0
    run = provenance.Run(argv)
    committed = default_robot_dir() / "gait_family.json"
    py = sys.executable
    rows: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="gait_build_") as tmp:
        tmp = Path(tmp)
        settings = None
        if args.quick:
            settings = write_settings(tmp / "gait_quick.yaml", **REDUCED)
        st = load_gait_settings(settings) if settings else load_gait_settings()
        extra = ["--settings", str(settings)] if settings else []
        plan = [] if args.skip_old else [("old", [py, "-m", "biped_controller.gaits.generation"], {})]
        if args.old_single_thread:
            plan.append(("old_blas1", [py, "-m", "biped_controller.gaits.generation"], {"OPENBLAS_NUM_THREADS": "1"}))
        bcmd = [py, "-m", "biped_controller.gaits.build", "--workers", str(args.workers)]
        today_cmd, today_env = bcmd + ["--no-memo"], {}
        if args.today_rev:
            today_env = _archive(args.today_rev, tmp / "today_src")
            today_cmd = bcmd
        for i in range(args.repeats):
            if args.today:
                plan.append((f"today_{i + 1}", today_cmd, today_env))
            plan.append((f"new_{i + 1}", bcmd, {}))
        for name, cmd, env in plan:
            d = tmp / name
            d.mkdir()
            out = d / "gait_family.json"
            env = dict(env, NUMBA_CACHE_DIR=str(d / "numba_cache"))
            print(f"{name}: {' '.join(cmd[1:])} ... (load {os.getloadavg()[0]:.2f})", flush=True)
            r = _run(cmd + ["--out", str(out)] + extra, env, d / "log.txt")
            r["module_file"] = _module_file(env)
            log = (d / "log.txt").read_text(encoding="utf-8", errors="replace").splitlines()
            r["log_tail"] = log[-3:]
            r["times_line"] = next((x for x in log if x.startswith("times [s]:")), None)
            if out.is_file():
                r["sha256"] = _sha(out)
                r["figures"] = _figures(out)
                r["accepted"], r["not_accepted"] = within_tolerance(json.loads(out.read_text())["validation"], st)
                if not args.quick:
                    r["vs_committed"] = _distance(out, committed)
                if args.keep:
                    args.keep.mkdir(parents=True, exist_ok=True)
                    (args.keep / f"{name}.json").write_bytes(out.read_bytes())
            rows[name] = r
            print(f"  {r['wall_s']:.1f} s, exit {r['exit']}, load after {r['load_after'][0]:.2f}", flush=True)
        if not args.skip_old and "old" in rows and (tmp / "old" / "gait_family.json").is_file():
            for name in rows:
                if name != "old" and (tmp / name / "gait_family.json").is_file():
                    rows[name]["vs_old"] = _distance(tmp / name / "gait_family.json", tmp / "old" / "gait_family.json")
    news = [r for k, r in rows.items() if k.startswith("new")]
    summary = {
        "target_s": TARGET_S,
        "new_wall_s": [r["wall_s"] for r in news],
        "new_identical_across_runs": len({r.get("sha256") for r in news}) == 1 and len(news) > 1,
        "old_wall_s": rows["old"]["wall_s"] if "old" in rows else None,
    }
    if summary["old_wall_s"] and news:
        summary["ratio_old_over_new"] = [round(summary["old_wall_s"] / r["wall_s"], 2) for r in news]
    todays = [r for k, r in rows.items() if k.startswith("today")]
    if todays:
        summary["today_wall_s"] = [r["wall_s"] for r in todays]
        summary["new_identical_to_today"] = (len({r.get("sha256") for r in news + todays}) == 1
                                             and None not in {r.get("sha256") for r in news + todays})
        # each new run against the today run just before it (the pair ran one after the other)
        summary["ratio_today_over_new"] = [round(t["wall_s"] / n["wall_s"], 3) for t, n in zip(todays, news)]
        summary["ratio_today_over_new_median"] = float(np.median(summary["ratio_today_over_new"]))
        summary["new_wall_s_median"] = float(np.median(summary["new_wall_s"]))
        summary["today_wall_s_median"] = float(np.median(summary["today_wall_s"]))
        summary["today_cpu_s"] = [r.get("cpu_s") for r in todays]
        summary["new_cpu_s"] = [r.get("cpu_s") for r in news]
    R = {"meta": {"date": provenance._utc_now(), "host": platform.node(), "cpus": os.cpu_count(),
                  "python": platform.python_version(), "blas": blas_info(), "quick": args.quick,
                  "settings": "reduced (benchmarks: --quick)" if args.quick else "robots/biped7/gait.yaml"},
         "summary": summary, "rows": rows}
    args.out.mkdir(parents=True, exist_ok=True)
    stem = "results" + (f"_{args.tag}" if args.tag else "") + ("_quick" if args.quick else "")
    jpath = args.out / f"{stem}.json"
    jpath.write_text(json.dumps(R, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    mpath = jpath.with_suffix(".md")
    mpath.write_text(markdown(R), encoding="utf-8")
    run.record(jpath, mpath)
    print(markdown(R))
    return 0


def markdown(R: dict) -> str:
    s = R["summary"]
    lines = [f"# Gait family built from nothing ({R['meta']['date']}, {R['meta']['cpus']} cores, "
             f"{'reduced family' if R['meta']['quick'] else 'robots/biped7'})", "",
             f"Target: at most {s['target_s']:.0f} s (printed, not asserted). New build identical across runs: "
             f"{s['new_identical_across_runs']}.", "",
             "| run | wall [s] | CPU [s] | load before / after (1 min) | held-out fit q [rad] | q' [rad/s] | fitted min margin | "
             "max periodicity between strides | range [m] | accepted | vs committed: q [rad] / q' [rad/s] / c |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, r in R["rows"].items():
        f = r.get("figures", {})
        vc = r.get("vs_committed")

        def g(k, fmt=".2e"):
            v = f.get(k)
            return format(v, fmt) if isinstance(v, (int, float)) and not isinstance(v, bool) else str(v)
        vcs = (f"{vc['max_abs_dq']:.2e} / {vc['max_abs_dqdot']:.2e} / {vc['max_abs_dc_strides']:.2e}" if vc else "-")
        lines.append(f"| {name} | {r['wall_s']:.1f} | {r.get('cpu_s', float('nan')):.1f} | {r['load_before'][0]:.2f} / {r['load_after'][0]:.2f} | "
                     f"{g('held_out_fit_error_q_max')} | {g('held_out_fit_error_qdot_max')} | {g('fitted_min_margin', '.4f')} | "
                     f"{g('fitted_max_periodicity_residual')} | {f.get('range')} | {r.get('accepted')} | {vcs} |")
    if "ratio_old_over_new" in s:
        lines += ["", f"old / new wall time: {s['ratio_old_over_new']}"]
    if "ratio_today_over_new" in s:
        lines += ["", f"today / new wall time (pairs run one after the other): {s['ratio_today_over_new']}; "
                      f"new file identical to today's: {s['new_identical_to_today']}"]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
