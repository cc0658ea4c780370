"""Generate (and check) ``config/gait_family.json``: optimised steps over the stride range, the
degree-7 fit b_ijk, validation figures, and the paper's own question (best stride at 1 m/s).

Run through ``scripts/generate_gait_family [--check] [--json FILE]``. Deterministic: the same settings
give the same file (wall-clock times are printed, never stored).
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

from biped_sim.settings import default_config_dir
from biped_sim.floating import impact_paper

from biped_sim.gait_family import GaitFamily, fit_family
from .gait_optimizer import StepOptimizer, StepSolution, basis, load_gait_settings
from .model import CONSTRAINT_NAMES, relabel


# Smoothing passes (weight of |c - c_fit(p)|^2 against the criterion scaled by 1e-4): increasing, so the
# family first relaxes towards the fit and is then held to it.
SMOOTHING_WEIGHTS = (1.0, 10.0, 100.0, 1000.0, 1000.0, 1.0e4, 1.0e4, 1.0e4, 1.0e4, 1.0e4)


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


def solve_family(opt: StepOptimizer, strides: list[float], p_d: float, progress: bool = True, max_sweeps: int = 4) -> dict[float, StepSolution]:
    """Solve p_d first (stated initial guess), then outwards, each stride warm-started from its neighbour."""
    order_up = sorted(s for s in strides if s > p_d)
    order_down = sorted((s for s in strides if s < p_d), reverse=True)
    n = len(strides)
    out: dict[float, StepSolution] = {}
    t0 = time.perf_counter()
    sol = opt.solve(p_d)
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


def _fit_from_solutions(sols: dict[float, StepSolution], p_d: float, degree: int) -> np.ndarray:
    ps = sorted(p for p in sols if sols[p].success)
    return fit_family(np.array(ps), np.array([sols[p].a for p in ps]), p_d, degree, centered=True)


def smooth_family(opt: StepOptimizer, sols: dict[float, StepSolution], p_d: float, weights: tuple[float, ...],
                  progress: bool = True) -> dict[float, StepSolution]:
    """Make the family smooth in p so that the degree-7 fit reproduces it: alternate (i) the fit b_ijk
    through p_d and (ii) re-solving every stride p != p_d with the smoothing term
    weight * |c - c_fit(p)|^2 added to the (scaled) criterion, warm-started at c_fit(p). Every stride
    stays an exactly feasible cyclic step; it trades a little criterion for smoothness (the paper's
    family is "sub-optimal" too). p_d itself is never changed: it stays the true optimum."""
    st = opt.st
    T = st.T
    scale = T ** np.arange(5)[None, :]
    for it, w in enumerate(weights):
        b = _fit_from_solutions(sols, p_d, st.stride_degree)
        fam = GaitFamily(b, T, p_d, min(sols), max(sols), center=p_d)
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
            b = _fit_from_solutions(sols, p_d, st.stride_degree)
            fam = GaitFamily(b, T, p_d, min(sols), max(sols), center=p_d)
            err = max(float(np.max(np.abs(fam.coefficients(p)[0] * scale - sols[p].c))) for p in sols if sols[p].success)
            sys.stderr.write(f"smoothing pass {it + 1} (weight {w:g}): {changed} strides re-solved, "
                             f"max coefficient misfit {err:.2e}\n")
    return sols


def valid_range(sols: dict[float, StepSolution], p_d: float) -> tuple[float, float]:
    """Largest interval of consecutive successful strides containing p_d."""
    ps = sorted(sols)
    i = ps.index(p_d)
    lo = i
    while lo - 1 >= 0 and sols[ps[lo - 1]].success:
        lo -= 1
    hi = i
    while hi + 1 < len(ps) and sols[ps[hi + 1]].success:
        hi += 1
    return ps[lo], ps[hi]


def check_family(fam: GaitFamily, records: list[dict], opt: StepOptimizer, fine: int = 400) -> dict:
    """Validation figures of a fitted family, computed from the file alone (no re-optimisation)."""
    T = fam.T
    s = np.linspace(0, 1, fine + 1)
    tt = s * T
    phi, dphi, _ = basis(s, T)
    fit_q, fit_v = 0.0, 0.0
    per_stride = []
    in_range = [r for r in records if fam.p_min - 1e-12 <= r["stride"] <= fam.p_max + 1e-12]
    for r in in_range:
        c = np.array(r["c"])
        q_opt, v_opt = phi @ c.T, dphi @ c.T
        q_fit = np.array([fam.evaluate(r["stride"], t).q for t in tt])
        v_fit = np.array([fam.evaluate(r["stride"], t).dq_dtau for t in tt])
        eq, ev = float(np.max(np.abs(q_fit - q_opt))), float(np.max(np.abs(v_fit - v_opt)))
        fit_q, fit_v = max(fit_q, eq), max(fit_v, ev)
        per_stride.append({"stride": r["stride"], "fit_error_q": eq, "fit_error_qdot": ev,
                           "criterion": r["criterion"], "periodicity_residual": r["periodicity_residual"],
                           "min_margin": r["min_margin"], "min_margin_name": r["min_margin_name"],
                           "min_clearance": r["min_clearance"], "impact_energy_fraction": r["impact_energy_fraction"]})
    # the fitted family between the optimised strides: true constraints, clearance, periodicity
    ps = sorted(r["stride"] for r in in_range)
    probes = sorted(set(ps + [0.5 * (a + b) for a, b in zip(ps[:-1], ps[1:])]))
    between = []
    fm = opt.fixed
    ft = opt.desc.foot
    for p in probes:
        worst, name, clear = math.inf, "", math.inf
        for k, t in enumerate(np.linspace(0, T, 201)):
            q, qd, qdd = fam.reference(p, 0.0, t, 1.0)
            m = fm.margins_direct(q, qd, qdd) / fm.row_scale
            i = int(np.argmin(m))
            if m[i] < worst:
                worst, name = float(m[i]), CONSTRAINT_NAMES[i]
            if 0 < k < 200:
                pose, _ = fm.swing_foot(q)
                clear = min(clear, min(pose[1] + l * math.sin(pose[2]) for l in (ft.l_min, ft.l_max)))
        q0, v0, _ = fam.reference(p, 0.0, 0.0, 1.0)
        qT, vT, _ = fam.reference(p, 0.0, T, 1.0)
        v_new, _ = impact_paper(opt.floating, qT, vT)
        per = max(float(np.max(np.abs(q0 - relabel(qT)))), float(np.max(np.abs(v0 - v_new))))
        land, _ = fm.swing_foot(qT)
        between.append({"stride": p, "min_margin": worst, "min_margin_name": name, "min_clearance": clear,
                        "periodicity_residual": per, "landing_error": float(np.max(np.abs(land - [p, 0, 0])))})
    return {"fit_error_q_max": fit_q, "fit_error_qdot_max": fit_v, "strides": per_stride, "fitted_family": between,
            "fitted_min_margin": min(b["min_margin"] for b in between),
            "fitted_min_clearance": min(b["min_clearance"] for b in between)}


def speed_question(opt: StepOptimizer, strides: list[float], v: float, warm: np.ndarray, progress: bool = True) -> dict:
    """At speed v, T = p / v: criterion of the optimal step for each stride (the paper's own question)."""
    out = []
    prev = warm
    T0 = opt.st.T
    for i, p in enumerate(strides):
        opt.st = dataclasses.replace(opt.st, T=p / v)
        opt.phi, opt.dphi, opt.ddphi = basis(opt.s, opt.st.T)
        from .gait_optimizer import simpson_weights
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
    from .gait_optimizer import simpson_weights
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


def fit_and_restrict(records: list[dict], st, opt: StepOptimizer) -> GaitFamily:
    """Fit b_ijk over the successful strides around p_d, then restrict the range the controller may use
    to where the *fitted* family passes the constraint and clearance checks (probes at and between the
    optimised strides)."""
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
    b = fit_family(np.array(used), a, st.p_d, st.stride_degree, centered=True)
    wide = GaitFamily(b, st.T, st.p_d, used[0], used[-1], center=st.p_d)
    between = check_family(wide, records, opt)["fitted_family"]
    p_min, p_max = clean_interval(between, st.p_d)
    return GaitFamily(b, st.T, st.p_d, p_min, p_max, meta={"fit_range": (used[0], used[-1])}, center=st.p_d)


def refit(path: Path) -> dict:
    """Re-fit and re-validate the committed stride solutions without re-optimising."""
    data = json.loads(path.read_text(encoding="utf-8"))
    opt = StepOptimizer()
    fam = fit_and_restrict(data["strides"], opt.st, opt)
    data["family"] = fam.to_dict()
    data["validation"] = check_family(fam, data["strides"], opt)
    data["validation"]["fit_range"] = list(fam.meta.get("fit_range", []))
    path.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    return data


def generate(path: Path, progress: bool = True, settings_path: Path | None = None) -> dict:
    opt = StepOptimizer(settings=load_gait_settings(settings_path) if settings_path else None)
    st = opt.st
    t0 = time.perf_counter()
    sols = solve_family(opt, list(st.strides), st.p_d, progress)
    sols = smooth_family(opt, sols, st.p_d, SMOOTHING_WEIGHTS, progress)
    t_family = time.perf_counter() - t0
    records = [_solution_record(sols[p]) for p in sorted(sols)]
    fam = fit_and_restrict(records, st, opt)
    t1 = time.perf_counter()
    speed = speed_question(opt, [0.35, 0.40, 0.45, 0.50, 0.55, 0.60, 0.65], 1.0, sols[st.p_d].c, progress)
    t_speed = time.perf_counter() - t1
    data = {
        "description": "Reference gait family q_d(p, tau) of the planar biped; generated by scripts/generate_gait_family",
        "family": fam.to_dict(),
        "settings": {k: v for k, v in st.raw.items()},
        "solver": {"name": "scipy.optimize.minimize(method='SLSQP')", "gradients": "exact (Pinocchio RNEA derivatives) on the grid; central differences of the impact map at the end of the step",
                   "initial_guess": "double-support postures at both ends, linear interpolation + swing-knee bump (StepOptimizer.initial_guess), for p_d; neighbours warm-started"},
        "strides": records,
        "speed_1mps": speed,
    }
    data["validation"] = check_family(fam, records, opt)
    data["validation"]["fit_range"] = list(fam.meta.get("fit_range", []))
    path.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    print(f"family: {t_family:.1f} s, 1 m/s sweep: {t_speed:.1f} s, total {time.perf_counter() - t0:.1f} s")
    return data


def print_report(data: dict, validation: dict) -> None:
    fam = data["family"]
    print(f"valid stride range (fitted family checked clean): [{fam['p_min']:.4f}, {fam['p_max']:.4f}] m, "
          f"fitted over {validation.get('fit_range')}, p_d = {fam['p_d']}, T = {fam['T']} s")
    print(f"{'p [m]':>7} {'ok':>3} {'C [N2m2s/m]':>12} {'period.res':>10} {'min margin':>10} {'(row)':<14} {'clear [mm]':>10} {'impact loss':>11} {'fit q':>9} {'fit qd':>9}")
    fit = {r["stride"]: r for r in validation["strides"]}
    for r in data["strides"]:
        f = fit.get(r["stride"])
        print(f"{r['stride']:7.3f} {('yes' if r['success'] else 'NO'):>3} {r['criterion']:12.1f} {r['periodicity_residual']:10.1e} "
              f"{r['min_margin']:10.3f} {r['min_margin_name']:<14} {1e3 * r['min_clearance']:10.2f} {100 * r['impact_energy_fraction']:10.1f}% "
              f"{(f['fit_error_q'] if f else float('nan')):9.1e} {(f['fit_error_qdot'] if f else float('nan')):9.1e}")
    print(f"worst fit error: q {validation['fit_error_q_max']:.2e} rad, q' {validation['fit_error_qdot_max']:.2e} rad/s")
    print(f"fitted family between strides: min margin {validation['fitted_min_margin']:.3f}, min clearance {1e3 * validation['fitted_min_clearance']:.2f} mm, "
          f"max periodicity residual {max(b['periodicity_residual'] for b in validation['fitted_family']):.1e}")
    sp = data.get("speed_1mps")
    if sp:
        print("at 1 m/s (T = p / v): " + ", ".join(f"p={r['stride']:.2f}: {r['criterion']:.0f}{'' if r['success'] else '(failed)'}" for r in sp["sweep"]))
        print(f"best sampled stride {sp['best_sampled_stride']} m, parabolic estimate {sp['best_stride_parabolic']}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--check", action="store_true", help="reload the committed file and print validation figures")
    ap.add_argument("--settings", type=Path, default=None, help="gait settings (default config/gait.yaml)")
    ap.add_argument("--refit", action="store_true", help="re-fit b_ijk and the valid range from the stored strides (no re-optimisation)")
    ap.add_argument("--json", type=Path, help="write the validation figures as JSON")
    ap.add_argument("--out", type=Path, default=default_config_dir() / "gait_family.json")
    args = ap.parse_args(argv)
    if args.refit:
        data = refit(args.out)
        validation = data["validation"]
    elif args.check:
        data = json.loads(args.out.read_text(encoding="utf-8"))
        fam = GaitFamily.load(args.out)
        validation = check_family(fam, data["strides"], StepOptimizer())
    else:
        data = generate(args.out, settings_path=args.settings)
        validation = data["validation"]
    print_report(data, validation)
    if args.json:
        args.json.write_text(json.dumps(validation, indent=1) + "\n", encoding="utf-8")
    ok = validation["fitted_min_margin"] > 0 and validation["fitted_min_clearance"] > 0
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
