"""The max-push table over seeds: survival as a probability where the settings draw noise.

For a cell (plant, profile, push onset, duration, direction, height) and ``seeds`` = N, seed index
i in 0..N-1 runs with the plant's noise seeded by ``uncertainty.trial_seed(cell, i)`` (recorded in each
trial record's ``seed``): the same seed at every force of the cell and for every controller (common
seeds), and its own unpushed walk and band (the band is the unpushed walk of the same seed and
controller). At a force F the batch is all N seeds; a seed whose
unpushed walk already falls (``Band.unpushed_fall``) and a trial ended by a controller fault are counted
apart (``excluded``), in no rate. The survival rate is k / n over the n counted seeds, with its Wilson 95 %
interval (:mod:`.uncertainty`).

Search, per mode: coarse batches at 0, coarse, 2 coarse, ... [N] (ascending, one batch at a time) until
the first whose Wilson interval lies wholly below the lowest crossing level (so that every crossing has
a force tried that bounds it from above), or the scan's top; then, per level c (0.9 and 0.5 by default), the
bracket (last coarse force with rate >= c, first with rate < c) bisected on complete batches to the
resolution (``uncertainty.crossing_search``; the levels share batches at equal forces). Every decision
is taken on a complete batch, whose trials are each a pure function of (settings, seed, push), so a
process pool, this process or Ray give the same answer.

Each (built-in mode, seed)'s band is run once per cell on the executor and handed with the seed's trials
(``trials.give_band``), so no worker walks it again. A trial under sensor noise on MuJoCo may be ended by the
early stop (``stop.applies_mujoco_sensors``: an approximation, measured; ``full_trials`` runs it in full).

Comparison (two or more modes): at every force both modes ran, seed index i pairs mode A's trial with
mode B's (the same seed); the pairs where both count give the difference of the survival rates with
Newcombe's paired interval (``uncertainty.paired_difference``), in ``comparisons``.

A profile without randomness (no sensor noise: ``record.seed_of`` is None) draws nothing a seed could
change: :func:`seeded_table` is then not used (the deterministic search, one trial per force, as before).
"""
from __future__ import annotations

import math
import sys
from dataclasses import replace

from biped_controller.closed_loop.executor import CountingBar, ProgressBar, make_executor
from biped_controller.studies.trial import record, trials, uncertainty
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.controller import resolve
from biped_controller.studies.trial.runs import DEFAULT_DURATION, DEFAULT_START, paper_push
from biped_controller.studies.trial.settings import RunSettings, check_settings, differences
from biped_controller.studies.trial.survival import survival_rule


def is_random(settings: RunSettings) -> bool:
    """The settings draw random numbers (the plant's sensor noise): seeds change the trials."""
    return record.seed_of(settings.perturbation) is not None


def cell_of(settings: RunSettings, *, start: float, duration: float, sign: float, height: float | None) -> dict:
    """The cell a seed is derived from (module docstring): plant, profile and the push window (not the
    controller: every controller runs the same seeds)."""
    return {"plant": settings.sim_config().plant, "profile": settings.profile, "start": float(start),
            "duration": float(duration), "direction": "forward" if sign > 0 else "backward",
            "height": None if height is None else float(height)}


def seeded_settings(settings: RunSettings, seed: int) -> RunSettings:
    """``settings`` with the plant's noise seeded by ``seed``."""
    return replace(settings, perturbation=replace(settings.perturbation, seed=int(seed)))


def seeded_trial(push, mode: str, settings: RunSettings) -> dict:
    """One trial of a seeded batch: ``trials.survives`` plus the seed's unpushed walk's fall
    (``unpushed_fall``, "" when it walked) and whether the trial counts (``counted``: neither that fall
    nor a controller fault)."""
    settings.activate()
    rec = trials.survives(push, mode, settings)
    band = trials.band(mode, push, settings)
    rec["unpushed_fall"] = band.unpushed_fall
    rec["counted"] = not band.unpushed_fall and rec.get("fault_kind") is None
    return rec


def _band_task(args: tuple):
    """The band of a seed's trials (``trials.band``: its unpushed walk), run in a worker."""
    push, mode, settings = args
    settings.activate()
    return trials.band(mode, push, settings)


def _task(args: tuple) -> dict:
    """One trial of a batch: (push, mode, settings, seed index[, the seed's band computed elsewhere])."""
    push, mode, settings, index = args[:4]
    band = args[4] if len(args) > 4 else None
    if band is not None:
        trials.give_band(mode, push, settings, band)
    return dict(seeded_trial(push, mode, settings), seed_index=index)


def seeded_table(modes: tuple[str, ...], seeds: int, resolution: float = 5.0, fmax: float = 2000.0,
                 coarse: float = 50.0, *, levels: tuple[float, ...] = uncertainty.DEFAULT_LEVELS,
                 duration: float = DEFAULT_DURATION, start: float = DEFAULT_START, height: float | None = None,
                 workers: int = 1, ray: str | None = None, progress: bool = True, sign: float = 1.0,
                 settings: RunSettings, executor=None) -> dict[str, dict]:
    """Per mode: the survival rate at every force tried (Wilson 95 %) and the forces where it crosses each
    of ``levels`` with their intervals (module docstring). Forces [N], window [start, start + duration) [s].
    ``executor``: one of ``closed_loop.executor`` to run the trials on (left open; None: one made from
    ``workers`` and ``ray`` and closed here)."""
    check_settings(settings)
    if not is_random(settings):
        raise ValueError("seeded_table needs settings that draw noise (record.seed_of is None)")
    if isinstance(seeds, bool) or int(seeds) != seeds or seeds < 1:
        raise uncertainty.UncertaintyError(f"the seed count must be an integer >= 1, got {seeds!r}")
    levels = tuple(sorted((uncertainty.check_level(c) for c in levels), reverse=True))
    if not (math.isfinite(resolution) and resolution > 0.0):
        raise uncertainty.UncertaintyError(f"the resolution must be a number > 0, got {resolution!r}")
    # the most the search can need: every coarse batch, then one bisection per level of one coarse step
    n_coarse = int(math.floor(fmax / coarse + 1e-9)) + 1
    n_bis = len(levels) * max(0, math.ceil(math.log2(max(coarse / resolution, 1.0))))
    bar = CountingBar(len(modes) * seeds * (n_coarse + n_bis),
                      ProgressBar(sys.stderr if progress else None, label="seeded max-push " + ",".join(modes)),
                      f"at most {n_coarse} coarse + {n_bis} bisection batches of {seeds} seeds per mode")
    ex = make_executor(workers, ray=ray, initializer=context) if executor is None else executor
    cell = cell_of(settings, start=start, duration=duration, sign=sign, height=height)
    common = [uncertainty.trial_seed(cell, i) for i in range(seeds)]
    seed_list = {m: common for m in modes}
    records: dict[str, list[dict]] = {m: [] for m in modes}
    # each (built-in mode, seed)'s band (its unpushed walk: the same for every force of the cell) run once, on the
    # executor, and handed to every trial of it, not run again by each worker that meets the seed (a plug-in
    # controller's trials compute their own)
    window = paper_push(0.0, start=start, duration=duration, height=height)
    bands: dict[tuple[str, int], object] = {}

    def run(batch: list[tuple[str, float]]) -> dict[tuple[str, float], tuple[int, int]]:
        need = sorted({(m, i) for m, _ in batch if resolve(m).adaptive for i in range(seeds)} - set(bands))
        if need:
            got = ex.map(_band_task, [((window, m, seeded_settings(settings, seed_list[m][i])),) for m, i in need])
            bands.update(zip(need, got))
        tasks = [(paper_push(sign * f, start=start, duration=duration, height=height), m,
                  seeded_settings(settings, s), i, bands.get((m, i))) for m, f in batch for i, s in enumerate(seed_list[m])]
        res = ex.map(_task, [(t,) for t in tasks], on_result=lambda r: bar())
        out = {}
        for (m, f), j in zip(batch, range(0, len(res), seeds)):
            recs = [dict(r, force=f) for r in res[j:j + seeds]]
            records[m] += recs
            out[(m, f)] = (sum(1 for r in recs if r["counted"] and r["survived"]),
                           sum(1 for r in recs if r["counted"]))
        return out

    rates: dict[str, dict[float, tuple[int, int]]] = {m: {} for m in modes}
    try:
        active = list(modes)
        f = 0.0
        while active and f <= fmax + 1e-9:
            got = run([(m, f) for m in active])
            for m in list(active):
                k, n = rates[m][f] = got[(m, f)]
                if n == 0 or uncertainty.wilson(k, n)[1] < levels[-1]:
                    active.remove(m)
            f += coarse
        crossings: dict[str, list[dict]] = {m: [] for m in modes}
        for m in modes:
            counted = any(n for _, n in rates[m].values())
            for c in levels:
                lo, hi = uncertainty.first_bracket(rates[m], c)
                if not counted:     # no rate at all: not a survival up to fmax, an undefined crossing
                    crossings[m].append({"level": c, "bracket": [None, None], "estimate": None,
                                         "interval": [None, None], "tried": [],
                                         "note": "undefined: no trial counted (every seed's unpushed walk fell or its "
                                                 "controller faulted)"})
                    continue
                if hi is None:
                    crossings[m].append({"level": c, "bracket": [lo, None], "estimate": None, "interval": [None, None],
                                         "tried": [], "note": f"no force up to {fmax:g} N had a rate below {c:g}"})
                    continue
                crossings[m].append(uncertainty.crossing_search(lambda x, m=m: run([(m, x)])[(m, x)], c, lo, hi,
                                                                resolution, rates=rates[m]))
    finally:
        if executor is None:
            ex.close()
    bar.close()
    rule = survival_rule()
    out = {}
    for m in modes:
        recs = sorted(records[m], key=lambda r: (r["force"], r["seed_index"]))
        rows = []
        for force in sorted(rates[m]):
            at = [r for r in recs if r["force"] == force]
            k, n = rates[m][force]
            row = uncertainty.rate_row(force, k, n, excluded=len(at) - n)
            row["unpushed_falls"] = sum(1 for r in at if r["unpushed_fall"])
            row["faults"] = sum(1 for r in at if r["fault_kind"] is not None)
            rows.append(row)
        out[m] = {"mode": m, "seeds": seeds, "seed_list": seed_list[m],
                  "cell": cell,
                  "levels": list(levels), "resolution": resolution, "coarse_step": coarse, "scan_max": fmax,
                  "estimator": uncertainty.ESTIMATOR, "interval_method": uncertainty.INTERVAL,
                  "rates": rows, "crossings": crossings[m], "settings": differences(settings),
                  "survival": rule.text(), "trials": recs}
    if len(modes) > 1:
        comps = compare_modes(out)
        for m in modes:
            out[m]["comparisons"] = [c for c in comps if m in (c["a"], c["b"])]
    return out


def compare_modes(results: dict[str, dict]) -> list[dict]:
    """Every pair of modes (a, b) in ``results``' order, at every force both ran: the paired 2 x 2 counts
    over the seed indices where both trials count, the difference of the rates (a - b) and its Newcombe
    interval (module docstring)."""
    out = []
    modes = list(results)
    for i, ma in enumerate(modes):
        for mb in modes[i + 1:]:
            ta = {(r["force"], r["seed_index"]): r for r in results[ma]["trials"]}
            tb = {(r["force"], r["seed_index"]): r for r in results[mb]["trials"]}
            rows = []
            for force in sorted({f for f, _ in ta} & {f for f, _ in tb}):
                pairs = [(ta[k], tb[k]) for k in ta if k[0] == force and k in tb and ta[k]["counted"] and tb[k]["counted"]]
                if not pairs:
                    continue
                a = sum(1 for x, y in pairs if x["survived"] and y["survived"])
                b = sum(1 for x, y in pairs if x["survived"] and not y["survived"])
                c = sum(1 for x, y in pairs if not x["survived"] and y["survived"])
                rows.append({"force": force, **uncertainty.paired_difference(a, b, c, len(pairs) - a - b - c)})
            out.append({"a": ma, "b": mb, "interval_method": uncertainty.DIFFERENCE_INTERVAL, "forces": rows})
    return out


def _fmt(x) -> str:
    return "-" if x is None else f"{x:g}"


def print_seeded(results: dict[str, dict]) -> None:
    """The table of :func:`seeded_table`: per mode the rate at each force tried and the crossings."""
    print("noise seeds: one per cell and seed index (trial.uncertainty.trial_seed), in place of the perturbation's "
          "seed; each trial's seed is in its record")
    for m, r in results.items():
        print(f"mode {m}: {r['seeds']} seeds per force; survival rate k/n (Wilson 95 %), seeds counted apart "
              f"(unpushed walk fell / controller fault)")
        print(f"  {'force [N]':>9} {'k/n':>7} {'rate':>6} {'Wilson 95 %':>17} {'apart':>9}")
        for row in r["rates"]:
            rate = "-" if row["rate"] is None else f"{row['rate']:.3f}"
            wi = "-" if row["wilson_lo"] is None else f"[{row['wilson_lo']:.3f}, {row['wilson_hi']:.3f}]"
            print(f"  {row['force']:9g} {row['survived']:>3}/{row['counted']:<3} {rate:>6} {wi:>17} "
                  f"{row['unpushed_falls']:>4}/{row['faults']:<4}")
        for c in r["crossings"]:
            lo, hi = c["interval"]
            if c["bracket"] == [None, None]:     # no trial counted: no bracket, no interval
                print(f"  crossing {100 * c['level']:g} %: {c['note']}")
                continue
            print(f"  crossing {100 * c['level']:g} %: {_fmt(c['estimate'])} N (bracket {_fmt(c['bracket'][0])}-"
                  f"{_fmt(c['bracket'][1])} N; interval [{'0' if lo is None else _fmt(lo)}, "
                  f"{'unbounded' if hi is None else _fmt(hi)}] N)" + (f" {c['note']}" if c.get("note") else ""))
    r0 = next(iter(results.values()))
    seen = set()
    for m, r in results.items():
        for comp in r.get("comparisons", []):
            if (comp["a"], comp["b"]) in seen:
                continue
            seen.add((comp["a"], comp["b"]))
            print(f"{comp['a']} - {comp['b']} on common seeds: difference of survival rates (paired 95 % interval, "
                  f"Newcombe 1998 method 10); seed pairs: survived by both controllers / {comp['a']} only / {comp['b']} only / "
                  f"neither")
            for row in comp["forces"]:
                print(f"  {row['force']:9g} {row['difference']:+.3f} [{row['lo']:+.3f}, {row['hi']:+.3f}]  "
                      f"{row['both']}/{row['a_only']}/{row['b_only']}/{row['neither']}")
    print(f"(estimator: {r0['estimator']}; interval: {r0['interval_method']}; resolution {r0['resolution']:g} N)")
