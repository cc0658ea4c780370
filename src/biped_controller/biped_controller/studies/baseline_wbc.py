"""The whole-body QP baseline against the paper's adaptation: one push, seen period by period.

``python -m biped_controller.studies.baseline_wbc [--force 300] [--out results/baseline_wbc] [--set K=V]``
runs the same push (forward, 25 ms at mid first step, the paper's cell) in modes none, wbc, both and
hybrid on the rigid plant, writes ``findings.json`` (per mode: outcome, fall instant and cause, impact
instants, periods where the whole-body QP was active and its rows, the state at the fall) and the
figure ``push_<F>N.png``: p, tau', the whole-body QP's active rows, |w - w*| and the impact instants
over time. ``--profile`` and ``--set`` take the names and keys of ``scripts/experiment`` (e.g. the plant rule
``liftoff_penetration``, or ``plant=mujoco``).

The 25 ms capability-map slice of modes none / wbc / both / hybrid and its goal check (hybrid >= max(both,
wbc)), once ``--slice-map`` here, is ``python -m lab.wbc_slice`` (``lab/README.md``).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from biped_model.fixed_foot import CONSTRAINT_NAMES
from biped_sim.plant.push import Push

from biped_controller.studies.trial.args import (StudyArgumentParser, add_settings_args, finite_float,
                                                 nonnegative_float, settings_from_args)
from biped_controller.studies.trial.runs import DEFAULT_DURATION, DEFAULT_START, paper_push, push_run
from biped_controller.studies import provenance

MODES = ("none", "wbc", "both", "hybrid")


def _active_rows(mask: int) -> list[str]:
    return [CONSTRAINT_NAMES[i] for i in range(len(CONSTRAINT_NAMES)) if mask >> i & 1]


def summarise(mode: str, res) -> dict:
    """Outcome of one run and what the whole-body stage did (periods, rows, deviation), the state at the
    fall (paper q, q' of the current stance, the last recorded margins and the tightest row)."""
    st, recs = res.statuses, res.records
    active = [s for s in st if s.wbc_status in (1, 2)]
    rows: dict[str, int] = {}
    for s in active:
        for r in _active_rows(int(s.wbc_active)):
            rows[r] = rows.get(r, 0) + 1
    out = {
        "mode": mode, "fallen": bool(res.fallen), "fall_cause": res.fall_cause, "fall_detail": res.fall_detail,
        "fall_time": None if math.isnan(res.fall_time) else float(res.fall_time),
        "steps_walked": int(res.steps_walked), "impacts": [float(i.t) for i in res.impacts],
        "wbc_periods_active": sum(s.wbc_status == 1 for s in st),
        "wbc_periods_infeasible": sum(s.wbc_status == 2 for s in st),
        "wbc_first_active": float(active[0].t) if active else None,
        "wbc_last_active": float(active[-1].t) if active else None,
        "wbc_rows_active_periods": rows,
        "wbc_max_deviation": float(max((s.wbc_deviation for s in st), default=0.0)),
        "qp_infeasible_periods": sum(s.qp_status == 2 for s in st),
        "p_max": float(max(s.p for s in st)), "tau_dot_max": float(max(s.tau_dot for s in st)),
        "tau_dot_min": float(min(s.tau_dot for s in st)),
    }
    if res.fallen and st:
        s, r = st[-1], recs[-1]
        out["at_fall"] = {"t": float(s.t), "tau": float(s.tau), "tau_dot": float(s.tau_dot), "p": float(s.p),
                          "q": np.asarray(r.q).tolist(), "qd": np.asarray(r.qd).tolist(),
                          "tightest": CONSTRAINT_NAMES[int(s.tightest)],
                          "margins": dict(zip(CONSTRAINT_NAMES, np.round(np.asarray(s.margins), 3).tolist())),
                          "wbc_status": int(s.wbc_status), "wbc_active": _active_rows(int(s.wbc_active)),
                          "last_impact": float(res.impacts[-1].t) if res.impacts else None,
                          "old_foot_velocity_after_last_impact":
                              np.asarray(res.impacts[-1].old_foot_velocity).tolist() if res.impacts else None}
    return out


def figure(runs: dict, push: Push, path: Path, plant: str = "rigid") -> None:
    """p, tau', the whole-body QP's active rows, |w - w*| and the impacts over time, one line per mode, for
    the runs of ``push``."""
    force, start, duration = push.force, push.start, push.duration
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(5, 1, figsize=(9, 11), sharex=True)
    for mode, res in runs.items():
        t = np.array([s.t for s in res.statuses])
        ax[0].plot(t, [s.p for s in res.statuses], label=mode)
        ax[1].plot(t, [s.tau_dot for s in res.statuses], label=mode)
        ax[3].plot(t, [s.wbc_deviation for s in res.statuses], label=mode)
        ax[4].plot(t, [s.zmp for s in res.statuses], label=mode)
        for i in res.impacts:
            for a in ax:
                a.axvline(i.t, color=a.lines[-1].get_color() if a.lines else "k", lw=0.5, ls=":")
        if res.fallen:
            ax[0].plot([res.fall_time], [res.statuses[-1].p], "x", color=ax[0].lines[-1].get_color(), ms=10)
    for k, mode in enumerate(m for m in runs if m in ("wbc", "hybrid")):
        res = runs[mode]
        for s in res.statuses:
            for i in range(len(CONSTRAINT_NAMES)):
                if int(s.wbc_active) >> i & 1:
                    ax[2].plot(s.t, i + 0.3 * k, "|", color="C%d" % list(runs).index(mode), ms=4)
    ax[2].set_yticks(range(len(CONSTRAINT_NAMES)))
    ax[2].set_yticklabels(CONSTRAINT_NAMES, fontsize=6)
    ax[0].set_ylabel("p [m]")
    ax[1].set_ylabel("tau' [-]")
    ax[2].set_ylabel("WBC active rows")
    ax[3].set_ylabel("|w - w*| [rad/s^2]")
    ax[4].set_ylabel("predicted l [m]")
    ax[4].set_xlabel("t [s] (dotted: impacts; x: fall)")
    ax[0].legend(fontsize=8)
    ax[4].set_xlim(0.0, min(1.5, max(float(r.statuses[-1].t) for r in runs.values()) + 0.05))
    ax[0].set_title(f"{force:g} N forward for {duration * 1e3:g} ms at t = {start:g} s ({plant} plant)")
    for a in ax:
        a.axvspan(start, start + duration, color="0.9")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = StudyArgumentParser(prog="python -m biped_controller.studies.baseline_wbc", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--force", type=finite_float, default=300.0, help="[N], + forward (on the back)")
    ap.add_argument("--out", type=Path, default=Path("results/baseline_wbc"))
    ap.add_argument("--start", type=nonnegative_float, default=DEFAULT_START, help="[s] onset of the push (default mid first step)")
    add_settings_args(ap, perturb=False, full_trials=False)
    ap.add_argument("--no-figure", action="store_true")
    args = ap.parse_args(argv)
    provenance.track(args.out, args=args, argv=argv)   # record of each file written (results/README.md)
    settings = settings_from_args(ap, args)
    args.out.mkdir(parents=True, exist_ok=True)
    push = paper_push(args.force, start=args.start)
    runs = {m: push_run(push, m, settings=settings) for m in MODES}
    out = {"force": args.force, "duration": DEFAULT_DURATION, "start": args.start,
           "overrides": args.overrides, "observer": args.observer, "profile": settings.profile,
           "argv": list(sys.argv[1:] if argv is None else argv),
           "modes": {m: summarise(m, r) for m, r in runs.items()}}
    tag = f"push_{args.force:g}N" + (f"_at_{args.start:g}s" if args.start != DEFAULT_START else "") + "".join("_" + o.replace("=", "_") for o in args.overrides)
    (args.out / f"{tag}.json").write_text(json.dumps(out, indent=1))
    for m, s in out["modes"].items():
        print(f"{m:<7} fallen={s['fallen']} {s['fall_cause'] or '-'} t={s['fall_time']} impacts={s['impacts']} "
              f"wbc active={s['wbc_periods_active']} infeasible={s['wbc_periods_infeasible']} rows={s['wbc_rows_active_periods']}")
    if not args.no_figure:
        figure(runs, push, args.out / f"{tag}.png", settings.sim_config().plant)
    return 0


if __name__ == "__main__":
    sys.exit(main())
