"""Generate (and check) ``robots/biped7/gait_family.json``: optimised steps over the stride range, the
degree-7 fit b_ijk, validation figures, and the paper's own question (best stride at 1 m/s).

Run through ``scripts/generate_gait_family [--check] [--json FILE]``. Deterministic on one machine with
one BLAS configuration: the same settings give the same file (wall-clock times are printed, never
stored). Not across BLAS configurations: SLSQP's subproblem goes through OpenBLAS, whose result changes
in the last bits with its thread count (the number of cores, ``OPENBLAS_NUM_THREADS``) and its kernel
(chosen from the CPU), and the chained warm-started solves carry that on (``gaits.blas``;
``benchmarks/gait_build.py --blas-probe``). ``gaits.build`` is the same algorithm on both cores with
single-threaded BLAS: one file for any number of cores of one CPU type.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from biped_model.description import load_description
from biped_model.robot import STAMP_KEY, description_hash
from biped_model.floating import impact_paper

from biped_model.gait_family import SPLINE, GaitFamily, fit_family, fit_spline_family
from biped_controller.gaits.optimizer import GaitSettings, StepOptimizer, StepSolution, basis, load_gait_settings
from biped_model.fixed_foot import CONSTRAINT_NAMES, relabel




def _bar(i: int, n: int, label: str) -> None:
    width = 30
    done = int(width * i / max(n, 1))
    sys.stderr.write(f"\r[{'#' * done}{'.' * (width - done)}] {i}/{n} {label:<40}")
    sys.stderr.flush()
    if i == n:
        sys.stderr.write("\n")


def _solution_record(sol: StepSolution) -> dict:
    return {
        "stride": sol.stride, "T": sol.T, "c": sol.c.tolist(), "a": sol.a.tolist(),
        "criterion": sol.criterion, "success": sol.success, "message": sol.message,
        "iterations": sol.iterations, "periodicity_residual": sol.periodicity_residual,
        "min_margin": sol.min_margin, "min_margin_name": sol.min_margin_name,
        "min_clearance": sol.min_clearance, "impact_energy_loss": sol.impact_energy_loss,
        "impact_energy_fraction": sol.impact_energy_fraction, "touchdown_speed": sol.touchdown_speed,
    }


def solve_family(opt: StepOptimizer, strides: list[float], p_d: float, progress: bool = True, max_sweeps: int = 4,
                 first_guess: np.ndarray | None = None) -> dict[float, StepSolution]:
    """Solve p_d first (stated initial guess, or ``first_guess``: normalised coefficients (6, 5), e.g. another
    robot's step at its p_d), then outwards, each stride warm-started from its neighbour."""
    order_up = sorted(s for s in strides if s > p_d)
    order_down = sorted((s for s in strides if s < p_d), reverse=True)
    n = len(strides)
    out: dict[float, StepSolution] = {}
    t0 = time.perf_counter()
    sol = opt.solve(p_d, c0=first_guess)
    out[p_d] = sol
    if progress:
        _bar(1, n, f"p={p_d:.3f} C={sol.criterion:.1f} ({time.perf_counter() - t0:.0f}s)")
    for chain in (order_up, order_down):
        prev = out[p_d]
        for s in chain:
            sol = opt.solve(s, c0=prev.c)
            if not sol.success:  # retry once from the stated initial guess
                alt = opt.solve(s)
                if alt.success and (not sol.success or alt.criterion < sol.criterion):
                    sol = alt
            out[s] = sol
            if sol.success:
                prev = sol
            if progress:
                _bar(len(out), n, f"p={s:.3f} C={sol.criterion:.1f} ok={sol.success} ({time.perf_counter() - t0:.0f}s)")
    # Continuation sweeps: re-solve every stride warm-started from its left neighbour (ascending), then
    # from its right neighbour (descending), keeping a new answer only if it is feasible and strictly
    # better. This pulls all strides, p_d included, into one basin so that the family is smooth in p.
    ps = sorted(out)
    for sweep in range(max_sweeps):
        changed = 0
        for order in (ps, ps[::-1]):
            for a, b in zip(order[:-1], order[1:]):
                if not out[a].success:
                    continue
                cand = opt.solve(b, c0=out[a].c)
                if cand.success and (not out[b].success or cand.criterion < out[b].criterion - 1e-6 * abs(out[b].criterion)):
                    out[b] = cand
                    changed += 1
        if progress:
            sys.stderr.write(f"continuation sweep {sweep + 1}: {changed} strides improved ({time.perf_counter() - t0:.0f}s)\n")
        if changed == 0:
            break
    return out


def fit_strides(ps: list[float], a: np.ndarray, st: GaitSettings, p_min: float | None = None,
                p_max: float | None = None, meta: dict | None = None, smoothing: bool = False) -> GaitFamily:
    """The family of ``st.representation`` fitted to the time coefficients ``a`` ((S, 6, 5)) of the
    strides ``ps``, exact at p_d.

    Spline: the family itself interpolates every stride (breakpoints = strides, C2 not-a-knot);
    with ``smoothing`` it is instead the least-squares spline on ``st.smoothing_breakpoints`` (coarser
    than the strides), the target the smoothing passes pull the strides towards. Polynomial: the
    degree-``st.stride_degree`` least-squares fit in both cases."""
    ps = [float(p) for p in ps]
    lo = ps[0] if p_min is None else p_min
    hi = ps[-1] if p_max is None else p_max
    if st.representation == SPLINE:
        if smoothing:
            bp = sorted({x for x in st.smoothing_breakpoints if ps[0] <= x <= ps[-1]} | {ps[0], ps[-1]})
        else:
            bp = ps
        Y = fit_spline_family(np.array(ps), a, st.p_d, np.array(bp))
        return GaitFamily.spline(bp, Y, st.T, st.p_d, lo, hi, meta=meta)
    b = fit_family(np.array(ps), a, st.p_d, st.stride_degree, centered=True)
    return GaitFamily(b, st.T, st.p_d, lo, hi, meta=meta, center=st.p_d)


def _fit_from_solutions(sols: dict[float, StepSolution], st: GaitSettings) -> GaitFamily:
    """The smoothing target: the fit of ``fit_strides(..., smoothing=True)`` through the successful strides."""
    ps = sorted(p for p in sols if sols[p].success)
    return fit_strides(ps, np.array([sols[p].a for p in ps]), st, smoothing=True)


def smooth_family(opt: StepOptimizer, sols: dict[float, StepSolution], p_d: float, weights: tuple[float, ...],
                  progress: bool = True) -> dict[float, StepSolution]:
    """Make the family smooth in p so that the fit reproduces it: alternate (i) the fit through p_d
    and (ii) re-solving every stride p != p_d with the smoothing term weight * |c - c_fit(p)|^2 added
    to the (scaled) criterion, warm-started at c_fit(p). Every stride stays an exactly feasible cyclic
    step; it trades a little criterion for smoothness (the paper's family is "sub-optimal" too). p_d
    itself is never changed: it stays the true optimum."""
    st = opt.st
    scale = st.T ** np.arange(5)[None, :]
    for it, w in enumerate(weights):
        fam = _fit_from_solutions(sols, st)
        changed = 0
        for p in sorted(sols):
            if p == p_d or not sols[p].success:
                continue
            target = fam.coefficients(p)[0] * scale
            cand = opt.solve(p, c0=target, target=target, weight=w)
            if cand.success:
                sols[p] = cand
                changed += 1
        if progress:
            fam = _fit_from_solutions(sols, st)
            err = max(float(np.max(np.abs(fam.coefficients(p)[0] * scale - sols[p].c))) for p in sols if sols[p].success)
            sys.stderr.write(f"smoothing pass {it + 1} (weight {w:g}): {changed} strides re-solved, "
                             f"max coefficient misfit {err:.2e}\n")
    return sols


def held_out_strides(opt: StepOptimizer, fam: GaitFamily, ps: list[float], weight: float,
                     progress: bool = True) -> list[StepSolution]:
    """Strides NOT used for the fit: every midpoint of two consecutive fitted strides, optimised by the
    same procedure as the fitted strides' last smoothing pass (criterion + ``weight`` |c - c_fam(p)|^2,
    warm-started at the family). Their distance to the family is the fit error between the strides."""
    scale = fam.T ** np.arange(5)[None, :]
    out = []
    mids = [0.5 * (a + b) for a, b in zip(ps[:-1], ps[1:])]
    for i, p in enumerate(mids):
        target = fam.coefficients(p)[0] * scale
        sol = opt.solve(p, c0=target, target=target, weight=weight)
        out.append(sol)
        if progress:
            _bar(i + 1, len(mids), f"held out p={p:.5f} ok={sol.success}")
    return out


def _fit_errors(fam: GaitFamily, records: list[dict], phi: np.ndarray, dphi: np.ndarray, tt: np.ndarray) -> list[dict]:
    """|q_fam - q_opt| and |q'_fam - q'_opt| (max over the step) for each record inside the range."""
    out = []
    for r in records:
        c = np.array(r["c"])
        q_opt, v_opt = phi @ c.T, dphi @ c.T
        g = [fam.evaluate(r["stride"], t) for t in tt]
        q_fit = np.array([x.q for x in g])
        v_fit = np.array([x.dq_dtau for x in g])
        out.append({"stride": r["stride"], "success": r["success"],
                    "in_range": bool(fam.p_min - 1e-12 <= r["stride"] <= fam.p_max + 1e-12),
                    "fit_error_q": float(np.max(np.abs(q_fit - q_opt))),
                    "fit_error_qdot": float(np.max(np.abs(v_fit - v_opt))),
                    "criterion": r["criterion"], "periodicity_residual": r["periodicity_residual"],
                    "min_margin": r["min_margin"], "min_margin_name": r["min_margin_name"],
                    "min_clearance": r["min_clearance"], "impact_energy_fraction": r["impact_energy_fraction"]})
    return out


def probe_family(fam: GaitFamily, p: float, opt: StepOptimizer, instants: int = 201) -> dict:
    """The fitted family at one stride p (p' = 0, tau' = 1): smallest true constraint margin (17 rows,
    no design margins, scaled as in the optimiser) over ``instants`` instants, smallest heel/toe height
    inside the step [m], periodicity residual through the impact map [rad, rad/s], landing error [m, rad]."""
    T = fam.T
    fm = opt.fixed
    ft = opt.desc.foot
    worst, name, clear = math.inf, "", math.inf
    for k, t in enumerate(np.linspace(0, T, instants)):
        q, qd, qdd = fam.reference(p, 0.0, t, 1.0)
        m = fm.margins_direct(q, qd, qdd) / fm.row_scale
        i = int(np.argmin(m))
        if m[i] < worst:
            worst, name = float(m[i]), CONSTRAINT_NAMES[i]
        if 0 < k < instants - 1:
            pose, _ = fm.swing_foot(q)
            clear = min(clear, min(pose[1] + l * math.sin(pose[2]) for l in (ft.l_min, ft.l_max)))
    q0, v0, _ = fam.reference(p, 0.0, 0.0, 1.0)
    qT, vT, _ = fam.reference(p, 0.0, T, 1.0)
    v_new, _ = impact_paper(opt.floating, qT, vT)
    per = max(float(np.max(np.abs(q0 - relabel(qT)))), float(np.max(np.abs(v0 - v_new))))
    land, _ = fm.swing_foot(qT)
    return {"stride": float(p), "min_margin": worst, "min_margin_name": name, "min_clearance": clear,
            "periodicity_residual": per, "landing_error": float(np.max(np.abs(land - [p, 0, 0])))}


def check_family(fam: GaitFamily, records: list[dict], opt: StepOptimizer, held_out: list[dict] | None = None,
                 fine: int = 400, probes_per_interval: int = 4, probe_many=None) -> dict:
    """Validation figures of a fitted family, computed from the file alone (no re-optimisation): fit
    errors at the fitted strides and at the held-out strides; the fitted family itself at
    ``probes_per_interval`` points per interval of consecutive strides (true constraints, clearance,
    periodicity); largest |dq/dp| and |d2q/dp2| (p' enters q_d'' through them, eq. 11).
    ``probe_many(fam, strides)``, when given, returns ``[probe_family(fam, p, opt) for p in strides]``
    (e.g. computed by worker processes; the same numbers)."""
    T = fam.T
    s = np.linspace(0, 1, fine + 1)
    tt = s * T
    phi, dphi, _ = basis(s, T)
    per_stride = _fit_errors(fam, records, phi, dphi, tt)
    held_all = _fit_errors(fam, held_out or [], phi, dphi, tt)
    held = [r for r in held_all if r["in_range"]]
    ps = sorted(r["stride"] for r in per_stride if r["in_range"])
    probes = [a + (b - a) * m / probes_per_interval for a, b in zip(ps[:-1], ps[1:]) for m in range(probes_per_interval)]
    probes.append(ps[-1])
    between = probe_many(fam, probes) if probe_many is not None else [probe_family(fam, p, opt) for p in probes]
    grid_p = np.linspace(fam.p_min, fam.p_max, 141)
    grid_t = np.linspace(0.0, T, 21)
    g = [fam.evaluate(p, t) for p in grid_p for t in grid_t]
    inside = [r for r in per_stride if r["in_range"]]
    out = {"fit_error_q_max": max(r["fit_error_q"] for r in inside),
           "fit_error_qdot_max": max(r["fit_error_qdot"] for r in inside),
           "strides": per_stride, "held_out": held_all, "fitted_family": between,
           "fitted_min_margin": min(b["min_margin"] for b in between),
           "fitted_min_clearance": min(b["min_clearance"] for b in between),
           "fitted_max_periodicity_residual": max(b["periodicity_residual"] for b in between),
           "max_abs_dq_dp": float(max(np.max(np.abs(x.dq_dp)) for x in g)),
           "max_abs_d2q_dp2": float(max(np.max(np.abs(x.d2q_dp2)) for x in g)),
           "representation": fam.representation}
    if held:
        out["held_out_fit_error_q_max"] = max(r["fit_error_q"] for r in held)
        out["held_out_fit_error_qdot_max"] = max(r["fit_error_qdot"] for r in held)
        out["held_out_all_feasible"] = all(r["success"] for r in held)
    return out


def speed_question(opt: StepOptimizer, strides: list[float], v: float, warm: np.ndarray, progress: bool = True) -> dict:
    """At speed v, T = p / v: criterion of the optimal step for each stride (the paper's own question)."""
    out = []
    prev = warm
    T0 = opt.st.T
    for i, p in enumerate(strides):
        opt.st = dataclasses.replace(opt.st, T=p / v)
        opt.phi, opt.dphi, opt.ddphi = basis(opt.s, opt.st.T)
        from biped_controller.gaits.optimizer import simpson_weights
        opt.w = simpson_weights(opt.n, opt.st.T)
        # warm start: same normalised shape
        sol = opt.solve(p, c0=prev)
        if not sol.success:
            alt = opt.solve(p)
            if alt.success:
                sol = alt
        if sol.success:
            prev = sol.c
        out.append({"stride": p, "T": p / v, "criterion": sol.criterion, "success": sol.success})
        if progress:
            _bar(i + 1, len(strides), f"1 m/s: p={p:.3f} C={sol.criterion:.1f} ok={sol.success}")
    opt.st = dataclasses.replace(opt.st, T=T0)
    opt.phi, opt.dphi, opt.ddphi = basis(opt.s, T0)
    from biped_controller.gaits.optimizer import simpson_weights
    opt.w = simpson_weights(opt.n, T0)
    ok = [r for r in out if r["success"]]
    best = min(ok, key=lambda r: r["criterion"]) if ok else None
    # parabola through the best point and its neighbours for a sub-grid estimate
    est = None
    if best is not None:
        i = [r["stride"] for r in ok].index(best["stride"])
        if 0 < i < len(ok) - 1:
            x = np.array([ok[i - 1]["stride"], ok[i]["stride"], ok[i + 1]["stride"]])
            y = np.array([ok[i - 1]["criterion"], ok[i]["criterion"], ok[i + 1]["criterion"]])
            A = np.vstack([x**2, x, np.ones(3)]).T
            a2, a1, _ = np.linalg.solve(A, y)
            if a2 > 0:
                est = float(-a1 / (2 * a2))
    return {"speed": v, "sweep": out, "best_sampled_stride": best["stride"] if best else None,
            "best_stride_parabolic": est}


def clean_interval(between: list[dict], p_d: float) -> tuple[float, float]:
    """Largest interval of probe strides around p_d on which the fitted family keeps every true
    constraint margin > 0 and the swing foot above the ground."""
    ps = [b["stride"] for b in between]
    ok = [b["min_margin"] > 0 and b["min_clearance"] > 0 for b in between]
    i = int(np.argmin(np.abs(np.array(ps) - p_d)))
    if not ok[i]:
        return p_d, p_d
    lo = i
    while lo - 1 >= 0 and ok[lo - 1]:
        lo -= 1
    hi = i
    while hi + 1 < len(ps) and ok[hi + 1]:
        hi += 1
    return ps[lo], ps[hi]


def fit_and_restrict(records: list[dict], st: GaitSettings, opt: StepOptimizer, probe_many=None) -> GaitFamily:
    """Fit the family over the successful strides around p_d, then restrict the range the controller
    may use to where the *fitted* family passes the constraint and clearance checks (probes at and
    between the optimised strides)."""
    sols_ok = {r["stride"]: r for r in records}
    ps = sorted(sols_ok)
    i = ps.index(st.p_d)
    lo, hi = i, i
    while lo - 1 >= 0 and sols_ok[ps[lo - 1]]["success"]:
        lo -= 1
    while hi + 1 < len(ps) and sols_ok[ps[hi + 1]]["success"]:
        hi += 1
    used = ps[lo:hi + 1]
    a = np.array([np.array(sols_ok[p]["a"]) for p in used])
    wide = fit_strides(used, a, st)
    between = check_family(wide, records, opt, probe_many=probe_many)["fitted_family"]
    p_min, p_max = clean_interval(between, st.p_d)
    return fit_strides(used, a, st, p_min, p_max, meta={"fit_range": (used[0], used[-1])})


def with_range(fam: GaitFamily, p_min: float, p_max: float) -> GaitFamily:
    """The same family (same coefficients) with the controller's range narrowed to [p_min, p_max]."""
    if fam.representation == SPLINE:
        return GaitFamily.spline(fam.breakpoints, fam.values, fam.T, fam.p_d, p_min, p_max, meta=fam.meta)
    return GaitFamily(fam.b, fam.T, fam.p_d, p_min, p_max, meta=fam.meta, center=fam.center)


def restrict_to_held_out(fam: GaitFamily, used: list[float], held: list[StepSolution], st: GaitSettings) -> GaitFamily:
    """Narrow the range to the largest interval of fitted strides around p_d on which every held-out
    stride (one per interval) was optimised and lies within the fit tolerances of the family: an
    interval whose midpoint misses is not verified, so the controller may not use it."""
    T = fam.T
    s = np.linspace(0.0, 1.0, 401)
    phi, dphi, _ = basis(s, T)
    recs = [_solution_record(h) for h in held]
    errs = {r["stride"]: r for r in _fit_errors(with_range(fam, used[0], used[-1]), recs, phi, dphi, s * T)}
    ok = []
    for a, b, r in zip(used[:-1], used[1:], recs):
        e = errs.get(r["stride"])
        ok.append(bool(r["success"] and e is not None and a < r["stride"] < b
                       and e["fit_error_q"] <= st.fit_tolerance_q and e["fit_error_qdot"] <= st.fit_tolerance_qdot))
    i = used.index(st.p_d)
    lo = i
    while lo > 0 and ok[lo - 1] and used[lo - 1] >= fam.p_min - 1e-12:
        lo -= 1
    hi = i
    while hi < len(used) - 1 and ok[hi] and used[hi + 1] <= fam.p_max + 1e-12:
        hi += 1
    return with_range(fam, max(used[lo], fam.p_min), min(used[hi], fam.p_max))


def _validate(fam: GaitFamily, data: dict, opt: StepOptimizer, probe_many=None) -> dict:
    v = check_family(fam, data["strides"], opt, data.get("held_out", []), probe_many=probe_many)
    v["fit_range"] = list(fam.meta.get("fit_range", [])) or [fam.p_min, fam.p_max]
    return v


def refit(path: Path, settings_path: Path | None = None, progress: bool = True,
          description_path: Path | None = None) -> dict:
    """Re-fit the family and its valid range from the committed (smoothed) stride solutions, re-solve
    the held-out strides against it (their targets depend on the family) and re-validate: every step
    of ``generate`` after the smoothing passes, without re-optimising the fitted strides (the robot of
    ``description_path``; None: the default robot)."""
    data = json.loads(path.read_text(encoding="utf-8"))
    opt = StepOptimizer(desc=load_description(description_path) if description_path else None,
                        settings=load_gait_settings(settings_path) if settings_path else None)
    st = opt.st
    records = data["strides"]
    fam = fit_and_restrict(records, st, opt)
    lo, hi = fam.meta["fit_range"]
    used = [r["stride"] for r in records if lo <= r["stride"] <= hi]
    held = held_out_strides(opt, fam, used, st.smoothing_weights[-1], progress)
    fam = restrict_to_held_out(fam, used, held, st)
    data["family"] = fam.to_dict()
    data["settings"] = dict(st.raw)
    data["held_out"] = [dict(_solution_record(h), smoothing_weight=st.smoothing_weights[-1]) for h in held]
    data["validation"] = _validate(fam, data, opt)
    data[STAMP_KEY] = {"description_sha256": description_hash(opt.desc)}
    path.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    return data


def generate(path: Path, progress: bool = True, settings_path: Path | None = None,
             description_path: Path | None = None, speed_sweep: bool = True,
             first_guess: np.ndarray | None = None) -> dict:
    """Optimise, smooth, fit and check the family of the robot ``description_path`` (None: the default
    robot's) with the settings ``settings_path`` (None: its gait.yaml) and write it to ``path``;
    ``speed_sweep`` False leaves out the 1 m/s question (``speed_1mps``); ``first_guess``: ``solve_family``'s."""
    opt = StepOptimizer(desc=load_description(description_path) if description_path else None,
                        settings=load_gait_settings(settings_path) if settings_path else None)
    st = opt.st
    t0 = time.perf_counter()
    sols = solve_family(opt, list(st.strides), st.p_d, progress, first_guess=first_guess)
    sols = smooth_family(opt, sols, st.p_d, st.smoothing_weights, progress)
    records = [_solution_record(sols[p]) for p in sorted(sols)]
    fam = fit_and_restrict(records, st, opt)
    lo, hi = fam.meta["fit_range"]
    used = [r["stride"] for r in records if lo <= r["stride"] <= hi]
    held = held_out_strides(opt, fam, used, st.smoothing_weights[-1], progress)
    fam = restrict_to_held_out(fam, used, held, st)
    t_family = time.perf_counter() - t0
    t1 = time.perf_counter()
    speed = (speed_question(opt, [0.35, 0.40, 0.45, 0.50, 0.55, 0.60, 0.65], 1.0, sols[st.p_d].c, progress)
             if speed_sweep else None)
    t_speed = time.perf_counter() - t1
    data = {
        "description": "Reference gait family q_d(p, tau) of the planar biped; generated by scripts/generate_gait_family",
        "family": fam.to_dict(),
        "settings": dict(st.raw),
        "solver": {"name": "scipy.optimize.minimize(method='SLSQP')", "gradients": "exact (Pinocchio RNEA derivatives) on the grid; central differences of the impact map at the end of the step",
                   "initial_guess": "double-support postures at both ends, linear interpolation + swing-knee bump (StepOptimizer.initial_guess), for p_d; neighbours warm-started"},
        "strides": records,
        "held_out": [dict(_solution_record(h), smoothing_weight=st.smoothing_weights[-1]) for h in held],
        **({"speed_1mps": speed} if speed is not None else {}),
    }
    data["validation"] = _validate(fam, data, opt)
    # the stamp (biped_model.robot): the description this family was built for
    data[STAMP_KEY] = {"description_sha256": description_hash(opt.desc)}
    path.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    print(f"family: {t_family:.1f} s, 1 m/s sweep: {t_speed:.1f} s, total {time.perf_counter() - t0:.1f} s")
    return data


def within_tolerance(validation: dict, st: GaitSettings) -> tuple[bool, list[str]]:
    """Acceptance of a validated family: fitted family clean between the strides, fit errors at the
    fitted and the held-out strides within the stated tolerances, every held-out stride feasible."""
    why = []
    if not validation["fitted_min_margin"] > 0:
        why.append(f"fitted family violates a true constraint (margin {validation['fitted_min_margin']:.3g})")
    if not validation["fitted_min_clearance"] > 0:
        why.append(f"fitted family's swing foot touches the ground ({validation['fitted_min_clearance']:.3g} m)")
    for key, tol in (("fit_error_q_max", st.fit_tolerance_q), ("fit_error_qdot_max", st.fit_tolerance_qdot),
                     ("held_out_fit_error_q_max", st.fit_tolerance_q), ("held_out_fit_error_qdot_max", st.fit_tolerance_qdot)):
        if key in validation and not validation[key] <= tol:
            why.append(f"{key} = {validation[key]:.3g} > {tol:g}")
    held_all = validation.get("held_out", [])
    held_in = [r for r in held_all if r.get("in_range", True)]
    if not held_all:
        why.append("no held-out stride inside the range")
    elif not held_in:
        why.append(collapsed_range_reason(held_all, st))
    elif not validation.get("held_out_all_feasible", False):
        why.append("a held-out stride could not be optimised: "
                   + ", ".join(f"{r['stride']:.4f} m" for r in held_in if not r["success"]))
    return not why, why


def collapsed_range_reason(held_out: list[dict], st: GaitSettings) -> str:
    """Why the valid range holds no held-out stride (it collapsed to p_d): the two held-out strides
    nearest p_d, each with whether it was optimised and its fit errors against the tolerances (the
    range stops at the first interval whose held-out stride misses, ``restrict_to_held_out``)."""
    near = sorted(held_out, key=lambda r: abs(r["stride"] - st.p_d))[:2]
    parts = [f"{r['stride']:.4f} m {'optimised' if r['success'] else 'NOT optimised'}, fit error q "
             f"{r['fit_error_q']:.2g} rad (tolerance {st.fit_tolerance_q:g}), q' {r['fit_error_qdot']:.2g} rad/s "
             f"(tolerance {st.fit_tolerance_qdot:g})" for r in sorted(near, key=lambda r: r["stride"])]
    return ("the valid range collapsed to p_d (no held-out stride inside it); the held-out strides next to p_d: "
            + "; ".join(parts) + " (docs/robots.md, 'NOT ACCEPTED with the range [p_d, p_d]')")


def print_report(data: dict, validation: dict) -> None:
    fam = data["family"]
    print(f"representation {fam.get('representation', 'polynomial_in_p')}; valid stride range (fitted family checked "
          f"clean): [{fam['p_min']:.4f}, {fam['p_max']:.4f}] m, fitted over {validation.get('fit_range')}, "
          f"p_d = {fam['p_d']}, T = {fam['T']} s")
    print(f"{'p [m]':>8} {'ok':>3} {'C [N2m2s/m]':>12} {'period.res':>10} {'min margin':>10} {'(row)':<14} {'clear [mm]':>10} {'impact loss':>11} {'fit q':>9} {'fit qd':>9}")
    fit = {r["stride"]: r for r in validation["strides"]}
    ho = {r["stride"]: r for r in validation.get("held_out", [])}
    rows = [(r, fit.get(r["stride"]), "") for r in data["strides"]]
    rows += [(r, ho.get(r["stride"]), "h") for r in data.get("held_out", [])]
    for r, f, tag in sorted(rows, key=lambda x: x[0]["stride"]):
        print(f"{r['stride']:7.4f}{tag or ' '} {('yes' if r['success'] else 'NO'):>3} {r['criterion']:12.1f} {r['periodicity_residual']:10.1e} "
              f"{r['min_margin']:10.3f} {r['min_margin_name']:<14} {1e3 * r['min_clearance']:10.2f} {100 * r['impact_energy_fraction']:10.1f}% "
              f"{(f['fit_error_q'] if f else float('nan')):9.1e} {(f['fit_error_qdot'] if f else float('nan')):9.1e}")
    print("(h: held-out stride, not used for the fit)")
    print(f"worst fit error at the fitted strides: q {validation['fit_error_q_max']:.2e} rad, q' {validation['fit_error_qdot_max']:.2e} rad/s")
    if "held_out_fit_error_q_max" in validation:
        print(f"worst fit error at the held-out strides: q {validation['held_out_fit_error_q_max']:.2e} rad, "
              f"q' {validation['held_out_fit_error_qdot_max']:.2e} rad/s")
    print(f"fitted family between strides: min margin {validation['fitted_min_margin']:.3f}, min clearance {1e3 * validation['fitted_min_clearance']:.2f} mm, "
          f"max periodicity residual {max(b['periodicity_residual'] for b in validation['fitted_family']):.1e}; "
          f"max |dq/dp| {validation.get('max_abs_dq_dp', float('nan')):.3g} rad/m, max |d2q/dp2| {validation.get('max_abs_d2q_dp2', float('nan')):.3g} rad/m^2")
    sp = data.get("speed_1mps")
    if sp:
        print("at 1 m/s (T = p / v): " + ", ".join(f"p={r['stride']:.2f}: {r['criterion']:.0f}{'' if r['success'] else '(failed)'}" for r in sp["sweep"]))
        print(f"best sampled stride {sp['best_sampled_stride']} m, parabolic estimate {sp['best_stride_parabolic']}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--check", action="store_true", help="reload the committed file and print validation figures")
    ap.add_argument("--settings", type=Path, default=None, help="gait settings (default robots/biped7/gait.yaml)")
    ap.add_argument("--refit", action="store_true", help="re-fit the family and the valid range from the stored strides and re-solve the held-out strides (the fitted strides are not re-optimised)")
    ap.add_argument("--json", type=Path, help="write the validation figures as JSON")
    ap.add_argument("--out", type=Path, default=None, help="the family file (default the robot's gait_family.json)")
    ap.add_argument("--robot", default=None, metavar="NAME|PATH",
                    help="the robot (a name under robots/ or a robot directory; default biped7): its description, "
                         "its gait.yaml (unless --settings) and its family file (unless --out); docs/robots.md")
    args = ap.parse_args(argv)
    from biped_model.robot import RobotError, resolve_robot
    try:
        robot = resolve_robot(args.robot)
        robot.description()
    except RobotError as exc:
        print(f"generate_gait_family: error: {exc}", file=sys.stderr)
        return 2
    desc_path = None if robot.is_default else robot.description_path
    if args.settings is None and not robot.is_default:
        args.settings = robot.gait_path
    if args.out is None:
        args.out = robot.family_path
    st = load_gait_settings(args.settings) if args.settings else load_gait_settings()
    if args.refit:
        data = refit(args.out, args.settings, description_path=desc_path)
        validation = data["validation"]
    elif args.check:
        data = json.loads(args.out.read_text(encoding="utf-8"))
        fam = GaitFamily.load(args.out)
        validation = _validate(fam, data, StepOptimizer(desc=robot.description() if desc_path else None, settings=st))
    else:
        data = generate(args.out, settings_path=args.settings, description_path=desc_path)
        validation = data["validation"]
    print_report(data, validation)
    if args.json:
        args.json.write_text(json.dumps(validation, indent=1) + "\n", encoding="utf-8")
    ok, why = within_tolerance(validation, st)
    for w in why:
        print(f"NOT ACCEPTED: {w}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
