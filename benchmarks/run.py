"""Benchmarks of the controller, the adaptation QP, the DDS lockstep and the in-process loop.

    python -m benchmarks.run [--quick] [--json FILE] [--md FILE]

Writes results/benchmarks/results.json (or --json) and results/benchmarks/results.md (or beside --json),
each with its provenance record (results/README.md). ``keys`` holds the stable dotted keys of this run's
sections and, merged from the sub-benchmarks' own files (``report.SUB_BENCHMARKS``, read from
``--sub-results``), the keys those separate runs produced; ``merged`` names each such file with its date.
Every timing is a median (p50) and a
99th percentile (p99) of per-call times measured with time.perf_counter_ns; the ratios compare
figures measured side by side in this one run (the machine is shared and noisy). Targets are
printed beside the results, never asserted. ``--quick``: a few hundred steps / instances (tests).

This module is the driver; each section is its own module: 0 ``hard_run`` (the recorded hard run), 1
``controller_step``, 2 ``solvers`` (and ``qp_bench``), 3 ``dds`` (``pingpong``, ``lockstep``), 4 ``inprocess``,
5 ``experiment_bench``, 6 ``sweep_bench``; ``common`` what they share, ``report`` the Markdown writer, the
stable keys and the merger of the sub-benchmarks' files. ``--controller``: ``plugin_bench`` instead.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from biped_controller.studies import provenance
from biped_controller.studies.trial.args import controller_arg

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # `python benchmarks/run.py`
    sys.path.insert(0, str(ROOT))
from benchmarks import RESULTS_DIR, common  # noqa: E402  (after the path above)
from benchmarks.common import TARGETS, ctrl_cfg, log  # noqa: E402
from benchmarks.controller_step import bench_controller  # noqa: E402
from benchmarks.dds import bench_lockstep, bench_pingpong  # noqa: E402
from benchmarks.experiment_bench import bench_experiment  # noqa: E402
from benchmarks.hard_run import find_hard_run, push_run, qp_counts  # noqa: E402
from benchmarks.inprocess import bench_inprocess, inprocess_only  # noqa: E402
from benchmarks.report import markdown, merge_sub_benchmarks, stable_keys  # noqa: E402
from benchmarks.solvers import bench_solvers  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="biped benchmarks")
    ap.add_argument("--quick", action="store_true", help="a few hundred steps / instances")
    ap.add_argument("--json", default=None,
                    help="default results/benchmarks/results.json (with --controller: results/benchmarks/plugin.json)")
    ap.add_argument("--md", default=None, help="Markdown table (default: results.md beside the JSON)")
    ap.add_argument("--sub-results", type=Path, default=RESULTS_DIR,
                    help="directory of the sub-benchmarks' files whose keys are merged (default: %(default)s)")
    ap.add_argument("--inprocess-only", action="store_true",
                    help="section 4 alone (the MuJoCo plant beside the rigid one): merged into the JSON as "
                         "'inprocess_side_by_side' with its own date and load average, with the keys "
                         "inprocess.mujoco.*; the rest of the JSON is left as it is")
    ap.add_argument("--profile", default=None, metavar="NAME",
                    help="a named profile of config/profiles/ for every controller and plant the bench builds "
                         "(default: the configuration files); a profile with a plant perturbation is refused")
    ap.add_argument("--robot", default=None, metavar="NAME|PATH",
                    help="the robot every section builds (a name under robots/ or a path; default biped7; "
                         "docs/robots.md); not with --controller")
    ap.add_argument("--controller", type=controller_arg, action="append", default=[], metavar="NAME",
                    help="instead of the bench's sections: the in-process speed of the named controller "
                         "(repeatable; a built-in mode, a registered controller or module:Class) walking on the "
                         "rigid plant beside the built-in modes (benchmarks/plugin_bench.py; --quick: 1 step, "
                         "1 repeat)")
    a = ap.parse_args(argv)
    if a.controller:
        if a.profile is not None or a.inprocess_only or a.robot is not None:
            ap.error("--controller times the configuration files' settings alone (no --profile, "
                     "no --inprocess-only, no --robot)")
        from benchmarks import plugin_bench
        return plugin_bench.main(["--json", a.json or str(RESULTS_DIR / "plugin.json")]
                                 + [x for n in a.controller for x in ("--controller", n)]
                                 + (["--steps", "1", "--repeats", "1"] if a.quick else []))
    if a.json is None:
        a.json = str(RESULTS_DIR / "results.json")
    from biped_controller.studies.trial.settings import OverrideError, differences, run_settings
    from biped_model.robot import RobotError
    try:
        common.SETTINGS = run_settings(profile=a.profile, robot=a.robot)
    except RobotError as exc:
        ap.error(str(exc))
    except (OverrideError, ValueError) as exc:
        ap.error(f"--profile {a.profile}: {exc}")
    if common.SETTINGS.perturbation is not None and not common.SETTINGS.perturbation.is_zero:
        ap.error(f"--profile {a.profile}: sets a plant perturbation; the bench times unperturbed plants")
    json_path = Path(a.json)
    md_path = Path(a.md) if a.md else json_path.with_suffix(".md")
    provenance.track(json_path, None if a.inprocess_only else md_path, argv=argv, plant="rigid,mujoco", robot=a.robot)
    if a.inprocess_only:
        return inprocess_only(json_path)
    T0 = time.perf_counter()
    quick = a.quick
    R = {"meta": {"date": time.strftime("%Y-%m-%d %H:%M:%S"), "quick": quick, "cpus": os.cpu_count(),
                  "settings": differences(common.SETTINGS),
                  "machine": platform.processor() or platform.machine(), "python": platform.python_version()},
         "targets": TARGETS}
    log("0. searching the hard run (largest surviving push, mode both)")
    hard = find_hard_run(quick)
    steps = 1 if quick else 22
    t0 = time.perf_counter()
    rec = push_run(hard["force"], steps)
    log(f"recorded F={hard['force']:.2f} N: {len(rec.records)} periods, fallen={rec.fallen} "
        f"[{time.perf_counter() - t0:.1f} s]")
    instances = [(hard["force"], q) for q in rec.qp_instances] + hard["instances"]
    R["hard_run"] = {"force": hard["force"], "bracket": hard["bracket"], "probes": hard["probes"],
                     "recorded": {"steps": steps, "periods": len(rec.records), "fallen": rec.fallen,
                                  "steps_walked": rec.steps_walked, **qp_counts(rec)}}
    log("1. controller step split")
    records = rec.records[:300] if quick else rec.records
    c = bench_controller(records, 300 if quick else 10_000)
    rec_dec = [(s.p_ddot, s.tau_ddot) for s in rec.statuses[:len(records)]]
    c["replay_matches_run"] = bool(np.allclose([d[:2] for d in c.pop("decisions")], rec_dec, rtol=1e-9, atol=1e-9))
    R["controller"] = c
    log(f"   total p50 {c['pieces_us']['total']['p50']:.1f} us; replay matches run: {c['replay_matches_run']}")
    log("2. QP solvers")
    cfg = ctrl_cfg("both")
    W = np.array([cfg.weight_p, cfg.weight_tau])
    if quick:   # every constrained instance (a few hundred at most) and 200 with x* feasible
        con = [i for i in instances if not np.all(i[1][0] @ i[1][2] - i[1][1] <= 0.0)]
        unc = [i for i in instances if np.all(i[1][0] @ i[1][2] - i[1][1] <= 0.0)]
        instances = con[:300] + unc[:200]
    R["solvers"] = bench_solvers(instances, W, 200 if quick else 10_000, 20 if quick else 500)
    log(f"   fastest correct: {R['solvers']['fastest_correct']}")
    log("2b. QP path head to head (benchmarks/qp_bench.py: early-out, held PIQP, exact-numba, direct DAQP/quadprog)")
    from benchmarks.qp_bench import run_bench
    qb = run_bench((250.0,) if quick else (250.0, 600.0), ("both",), 5 if quick else 30)
    R["qp_bench"] = {k: qb.get(k) for k in ("early_out_p50_us", "piqp_ratio_to_fastest",
                                             "piqp_ratio_to_fastest_qpsolvers", "exact_numba_ratio_to_fastest")}
    log(f"   early-out p50 {R['qp_bench']['early_out_p50_us']} us; PIQP path / fastest direct "
        f"{R['qp_bench']['piqp_ratio_to_fastest']}")
    log("3. DDS ping-pong and lockstep")
    pp = bench_pingpong(300 if quick else 5000)
    R["dds"] = {"pingpong": pp, "lockstep": bench_lockstep(0.5 if quick else 5.0, pp)}
    log(f"   ping-pong {pp.get('rate_hz', 'failed')}; lockstep {R['dds']['lockstep'].get('steps_per_s', R['dds']['lockstep'].get('reason'))}")
    log("4. in-process speed")
    R["inprocess"] = bench_inprocess(1, repeats=1) if quick else bench_inprocess(5)
    log("5. max-push table")
    R["experiment"] = bench_experiment(quick)
    log("6. sweep: the default capability map (early stop, bracketed search)")
    from benchmarks.sweep_bench import bench_sweep
    R["sweep"] = bench_sweep(quick)
    R["meta"]["wall_s"] = time.perf_counter() - T0
    R["keys"] = stable_keys(R)
    merge_sub_benchmarks(R, a.sub_results)
    p50 = c["pieces_us"]["total"]["p50"]
    prod = R["solvers"]["table_us"]["PIQP held (AdaptationQP)"]["ratio_to_fastest"]
    ls = R["dds"]["lockstep"]
    e = R["experiment"]
    R["target_check"] = {
        "controller_step_p50_us": {"value": p50, "target": "<= 30", "met": p50 <= 30},
        "production_qp_vs_fastest_ratio": {"value": prod, "target": "<= 1.5", "met": prod is not None and prod <= 1.5},
        "lockstep_vs_pingpong_fraction": {"value": ls.get("fraction_of_pingpong"), "target": ">= 0.90",
                                          "met": None if not ls.get("available") else ls.get("fraction_of_pingpong", 0) >= 0.9},
        "lockstep_rate_hz": {"value": ls.get("steps_per_s"), "target": ">= 1000",
                             "met": None if not ls.get("available") else ls["steps_per_s"] >= 1000},
        "inprocess_realtime_factor": {"value": R["inprocess"]["both"]["realtime_factor"], "target": ">= 50",
                                      "met": R["inprocess"]["both"]["realtime_factor"] >= 50},
        "max_push_table_s": {"value": e.get("parallel_s"), "target": "<= 30",
                             "met": None if not e.get("available") else e["parallel_s"] <= 30},
    }
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(R, indent=1, default=float) + "\n", encoding="utf-8")
    md = markdown(R)
    md_path.write_text(md, encoding="utf-8")
    print(md)
    log(f"wrote {json_path} and {md_path} [{R['meta']['wall_s']:.0f} s]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
