"""The capability map over seeds (``scripts/capability_map --seeds N`` on settings that draw noise): per
cell (direction, onset phase, duration) every mode's survival rates and 90 % / 50 % crossings, and the
modes compared on common seeds.

Each cell is one call of ``trial.seeded.seeded_table`` with the map's push window (start = phase x T, T
the preferred gait's period; forward +, backward -; the push height of the map) and the map's search
ranges (coarse step, the scan's top for the duration, the resolution): the same estimator, intervals and
comparison as the max-push table over seeds (docs/experiments.md, "Survival over seeds"). All modes of a
cell run in the same batches on one executor (a process pool of ``--workers``, or Ray), so the answer
does not depend on where the trials ran.

Resume: each finished cell is appended to the store (JSON Lines) under its key (the cell, the modes, the
seed count, the levels, the search and the settings' differences from config/); a rerun with the same
key takes the cell from the store. The key holds no code version: after a change to the closed loop or
the search, start a new store.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from biped_controller.closed_loop.executor import make_executor
from biped_controller.studies.capmap.spec import MapSpec, onset_time
from biped_controller.studies.trial import seeded, stop, uncertainty
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.settings import differences


def _key(spec: MapSpec, direction: str, phase: float, duration: float, seeds: int, levels) -> dict:
    s = spec.search.for_duration(duration)
    key = {"direction": direction, "phase": phase, "duration": duration, "modes": list(spec.modes),
           "seeds": seeds, "levels": list(levels), "coarse": s.coarse, "max": s.fmax,
           "resolution": s.resolution, "height": spec.height,
           "settings": json.loads(json.dumps(differences(spec.settings)))}
    if stop.stops_early(spec.settings):
        # trials ended early by the stop under sensor noise (stop.applies_mujoco_sensors): its settings; a cell's
        # key without them is the cell's trials run in full (every store made before that stop existed)
        key["early_stop"] = stop.identity(spec.settings)
    return key


def _load(store: Path | None) -> list[dict]:
    if store is None or not store.exists():
        return []
    return [json.loads(line) for line in store.read_text(encoding="utf-8").splitlines() if line.strip()]


def seeded_map(spec: MapSpec, seeds: int, levels=uncertainty.DEFAULT_LEVELS, *, workers: int = 1,
               ray: str | None = None, store: Path | None = None, log=sys.stdout, simulate: bool = True) -> dict:
    """Every cell of ``spec`` over ``seeds`` seeds (module docstring): {"cells": [{direction, phase,
    duration, start, modes: {mode: seeded_table's result without its trial records}, comparisons,
    trials, wall_time (s, of the run that simulated the cell; None when its store line predates it)}],
    "trials_run", "cells_resumed", "cells_missing", "wall_time"}. Trial records are kept in the store only.
    ``simulate`` False: only the cells the store holds (the others listed in ``cells_missing``)."""
    T = context(spec.settings.activate().robot).family.T
    done = {json.dumps(r["key"], sort_keys=True): r for r in _load(store)}
    cells, missing, run, resumed, t0 = [], [], 0, 0, time.perf_counter()
    ex = None
    try:
        for duration in spec.durations:
            s = spec.search.for_duration(duration)
            for direction in spec.directions:
                for phase in spec.phases:
                    key = _key(spec, direction, phase, duration, seeds, levels)
                    k = json.dumps(key, sort_keys=True)
                    if k in done:
                        res, resumed = done[k]["result"], resumed + 1
                        wall = done[k].get("wall_time")
                    elif not simulate:
                        missing.append({"direction": direction, "phase": phase, "duration": duration})
                        continue
                    else:
                        if ex is None:
                            ex = make_executor(workers, ray=ray, initializer=context)
                        t1 = time.perf_counter()
                        res = seeded.seeded_table(spec.modes, seeds, s.resolution, s.fmax, s.coarse, levels=levels,
                                                  duration=duration, start=onset_time(phase, T), height=spec.height,
                                                  sign=1.0 if direction == "forward" else -1.0, progress=log is not None,
                                                  settings=spec.settings, executor=ex)
                        n = sum(len(r["trials"]) for r in res.values())
                        run += n
                        wall = time.perf_counter() - t1
                        if store is not None:
                            store.parent.mkdir(parents=True, exist_ok=True)
                            with store.open("a", encoding="utf-8") as fh:
                                fh.write(json.dumps({"key": key, "result": res, "wall_time": wall},
                                                    allow_nan=False) + "\n")
                        if log is not None:
                            print(f"cell {direction} phase {phase:g} {duration:g} s: {n} trials in "
                                  f"{time.perf_counter() - t1:.1f} s; " + "; ".join(
                                      f"{m} " + ", ".join(f"{100 * c['level']:g} % {_g(c['estimate'])} N"
                                                          for c in r["crossings"]) for m, r in res.items()),
                                  file=log, flush=True)
                    cells.append({"direction": direction, "phase": phase, "duration": duration,
                                  "start": onset_time(phase, T),
                                  "trials": sum(len(r["trials"]) for r in res.values()), "wall_time": wall,
                                  "modes": {m: {k2: v for k2, v in r.items() if k2 not in ("trials", "comparisons")}
                                            for m, r in res.items()},
                                  "comparisons": next(iter(res.values())).get("comparisons", [])})
    finally:
        if ex is not None:
            ex.close()
    return {"cells": cells, "seeds": seeds, "levels": list(levels), "modes": list(spec.modes),
            "trials_run": run, "cells_resumed": resumed, "cells_missing": missing, "wall_time": time.perf_counter() - t0,
            "estimator": uncertainty.ESTIMATOR, "interval_method": uncertainty.INTERVAL,
            "difference_interval": uncertainty.DIFFERENCE_INTERVAL}


def _g(x) -> str:
    return "-" if x is None else f"{x:g}"


def crossing_table(result: dict) -> list[str]:
    """Markdown rows: per cell and mode, the crossings with their intervals."""
    levels = result["levels"]
    head = "| direction | phase | mode | " + " | ".join(f"{100 * c:g} % crossing [N] (interval)" for c in levels) + " |"
    out = [head, "|" + " --- |" * (3 + len(levels))]
    for cell in result["cells"]:
        for m, r in cell["modes"].items():
            parts = []
            for c in r["crossings"]:
                lo, hi = c["interval"]
                parts.append(f"{_g(c['estimate'])} ([{'0' if lo is None else _g(lo)}, "
                             f"{'unbounded' if hi is None else _g(hi)}])")
            out.append(f"| {cell['direction']} | {cell['phase']:g} | {m} | " + " | ".join(parts) + " |")
    return out


def band_figure(result: dict, path: Path) -> Path:
    """Per direction, over the onset phase: each mode's band between its 90 % and 50 % crossings (filled),
    the crossings' intervals as vertical bars (an unbounded end is left open)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    dirs = sorted({c["direction"] for c in result["cells"]}, key=["forward", "backward"].index)
    fig, axes = plt.subplots(1, len(dirs), figsize=(6.0 * len(dirs), 4.2), squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, d in zip(axes[0], dirs):
        cells = sorted((c for c in result["cells"] if c["direction"] == d), key=lambda c: c["phase"])
        for j, m in enumerate(result["modes"]):
            col = colours[j % len(colours)]
            ph = [c["phase"] for c in cells]
            est = {lev: [next(x["estimate"] for x in c["modes"][m]["crossings"] if x["level"] == lev) for c in cells]
                   for lev in result["levels"]}
            hi_l, lo_l = max(result["levels"]), min(result["levels"])
            ok = [i for i in range(len(ph)) if est[hi_l][i] is not None and est[lo_l][i] is not None]
            ax.fill_between([ph[i] for i in ok], [est[hi_l][i] for i in ok], [est[lo_l][i] for i in ok],
                            color=col, alpha=0.3, label=f"{m}: {100 * hi_l:g} %-{100 * lo_l:g} % band")
            for lev, style in ((hi_l, "-"), (lo_l, "--")):
                ax.plot(ph, [float("nan") if e is None else e for e in est[lev]], style, color=col, marker="o", ms=3)
            for i, c in enumerate(cells):
                for x in c["modes"][m]["crossings"]:
                    lo, hi = x["interval"]
                    if x["estimate"] is None:
                        continue
                    off = (j - 0.5) * 0.006
                    ax.plot([c["phase"] + off] * 2, [x["estimate"] if lo is None else lo,
                                                     x["estimate"] if hi is None else hi], color=col, lw=0.8)
        ax.set_xlabel("onset phase of the first step")
        ax.set_ylabel("push force [N]")
        ax.set_title(f"{d}, {result['seeds']} seeds per force")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
