"""Where the stance foot's |dF_z| tail lives on MuJoCo (a research script, not product code). Usage (from the
repository root)::

    .venv/bin/python -m lab.benchmarks.foot_tail [--steps 20] [--set KEY=VALUE ...] [--perturb FIELD=VALUE ...]
        [--threshold 200] [--json FILE]

One undisturbed walk (mode both, default profile, ``--set``/``--perturb`` as ``foot_quiet``), the plant's
``probe`` reading MuJoCo's contact list after every MuJoCo step: the normal force [N] of each sole sphere of
both feet (the force MuJoCo applied over that step). Over the periods ``foot_quiet`` counts (>= 10 ms after a
touchdown), each pair of consecutive periods of one stance gives dF_z = F_z(k) - F_z(k-1) [N] (``wrench``'s
F_z, the period's mean). A pair is *large* when |dF_z| > ``threshold`` (200 N, the target's p99). Reported:

* ``where``: the large pairs' share by time since the last touchdown (5 ms bins to 50 ms, then 25 ms bins)
  and by the controller's gait phase tau [s] (the status' ``tau`` at the later period, bins of 0.05 s, the last open), each with
  the share of all pairs in that bin (a bin with many large pairs but as many pairs is not special);
* ``with``: means over large and over the other pairs of what changes with them: |d tau_ankle| [N m] (the
  stance ankle's held torque, paper index 0, between the two periods), the largest |d tau| of the other five
  joints, the change in the number of engaged stance spheres (normal force > 0) between the periods' last
  MuJoCo steps, whether the sphere carrying the most load changed, the swing foot's mean normal force [N]
  (> 0: the other foot on the floor: the rear foot's lift-off or an impact), and the hip's vertical
  acceleration change [m/s^2] (the body's vertical mode on the soft contact);
* ``hops``: the MuJoCo steps of counted periods in which no sphere of the stance foot carries any force (the
  flat, loaded foot off the floor for a step), the periods holding one, and the share of large and of other
  pairs next to one (the pair's periods or the period before);
* ``alternation``: the lag-1 autocorrelation of dF_z within stances and the share of large pairs whose next
  pair has the opposite sign and > half its size: a share near 1 is a period-2 limit cycle (the held torque
  and the contact's response alternating period by period), near 0 isolated jumps;
* ``largest_trace`` (``--trace``): every MuJoCo step from 3 ms before the largest pair to 2 ms after it:
  the period's held stance-ankle torque [N m], the stance spheres' normal forces [N] and the stance ankle's
  height [um] (at the step's start), the stance foot's pitch rate [rad/s] (at its end);
* ``spectrum``: the frequency [Hz] of the largest peak of the stance feet's per-MuJoCo-step normal force
  (counted stretches only, mean removed) and its share of the spectrum's power above 20 Hz.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from biped_model.description import load_description
from biped_model.mjcf import foot_geom_names
from biped_controller.studies import provenance
from biped_controller.closed_loop import runner
from lab.foot_quiet import SKIP, measure
from biped_controller.studies.trial.settings import parse_overrides, parse_perturbation
from biped_model.gait_family import GaitFamily


class SphereProbe:
    """After each MuJoCo step (its end time [s], the plant's stance): per-sphere normal forces of both feet [N]
    (rows left, right) and the stance ankle's height [m] at the step's start (MuJoCo's contact forces and
    poses of the step), the hip's vertical velocity and the stance foot's pitch rate [rad/s, counter-clockwise]
    at its end."""

    def __init__(self, plant):
        import mujoco
        m = plant.model
        n = max(1, plant.cfg.mujoco_sole_points)
        self.n = n
        self.map = {}
        for k, side in enumerate(("left", "right")):
            for i, name in enumerate(foot_geom_names(side, plant.cfg.mujoco_sole_points)):
                self.map[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)] = (k, i)
        self.t, self.stance, self.force, self.zdot, self.pitch_rate, self.ankle_z = [], [], [], [], [], []
        self._foot_body = plant._foot_body

    def __call__(self, plant):
        d = plant.data
        f = np.zeros((2, self.n))
        for c in range(d.ncon):
            con = d.contact[c]
            if con.efc_address < 0:
                continue
            g = con.geom[0] if con.geom[0] in self.map else con.geom[1]
            if g in self.map:
                k, i = self.map[g]
                f[k, i] += d.efc_force[con.efc_address]
        self.t.append(float(d.time))
        self.stance.append(plant.stance)
        self.force.append(f)
        self.zdot.append(float(d.qvel[1]))
        j = 3 if plant.stance == 0 else 6
        self.pitch_rate.append(float(d.qvel[2] + d.qvel[j:j + 3].sum()))
        self.ankle_z.append(float(d.xpos[self._foot_body[plant.stance]][2]))


def walk(steps: int, overrides: tuple[str, ...], perturb: tuple[str, ...]):
    """The walk, its records and statuses, and the probe's per-MuJoCo-step series."""
    settings = parse_overrides(tuple(overrides) + ("plant=mujoco",))
    scfg = settings.sim_config()
    loop = runner.ClosedLoop(scfg, settings.ctrl_config("both"), GaitFamily.load(), load_description(),
                             parse_perturbation(tuple(perturb)))
    probe = SphereProbe(loop.sim)
    loop.sim.probe = probe
    loop.reset()
    r = loop.run(steps, limit=(steps + 3) * GaitFamily.load().T * 3, compiled_loop=False)
    return r, probe


def _share(mask_big, mask_bin):
    nb = int(mask_big.sum())
    return {"large": int((mask_big & mask_bin).sum()), "large_share": float((mask_big & mask_bin).sum() / nb) if nb else None,
            "pairs": int(mask_bin.sum())}


def analyse(r, probe, threshold: float, trace: bool = False) -> dict:
    recs = r.records
    t = np.array([x.t for x in recs])
    tend = np.array([x.t_end for x in recs])
    fz = np.array([x.wrench[1] for x in recs])
    tq = np.array([x.torque for x in recs])
    status_tau = {round(s.t, 9): s.tau for s in r.statuses}
    tau = np.array([status_tau.get(round(x, 9), np.nan) for x in t])
    touch = np.concatenate(([t[0]], [i.t for i in r.impacts]))
    sup = np.searchsorted(touch, t, side="right") - 1
    since = t - touch[sup]
    keep = since >= SKIP - 1e-9
    # per MuJoCo step series, mapped to their period
    pt = np.array(probe.t)
    pst = np.array(probe.stance)
    pf = np.array(probe.force)                       # (steps, 2, n)
    pzd = np.array(probe.zdot)
    per = np.searchsorted(tend, pt - 1e-12, side="left")   # the period whose (t, t_end] holds the step's end
    n_per = len(recs)
    stance_f = pf[np.arange(len(pt)), pst]            # the stance foot's spheres (the plant's stance at the step)
    swing_f = pf[np.arange(len(pt)), 1 - pst].sum(1)
    engaged_last = np.zeros(n_per)
    top_last = np.full(n_per, -1)
    swing_mean = np.zeros(n_per)
    zacc = np.full(n_per, np.nan)
    for k in range(n_per):
        m = np.nonzero(per == k)[0]
        if len(m) == 0:
            continue
        engaged_last[k] = float((stance_f[m[-1]] > 0).sum())
        top_last[k] = int(np.argmax(stance_f[m[-1]]))
        swing_mean[k] = float(swing_f[m].mean())
        zacc[k] = (pzd[m[-1]] - (pzd[m[0] - 1] if m[0] > 0 else pzd[m[0]])) / (tend[k] - t[k])
    idx = np.nonzero(keep)[0]
    a, b = idx[:-1], idx[1:]
    same = (sup[a] == sup[b]) & (b == a + 1)
    a, b = a[same], b[same]
    d = fz[b] - fz[a]
    big = np.abs(d) > threshold
    out: dict = {"threshold": threshold, "pairs": int(len(d)), "large": int(big.sum()),
                 "p99": float(np.percentile(np.abs(d), 99)) if len(d) else None}
    s_b = since[b]
    edges = list(np.arange(0.010, 0.050 + 1e-9, 0.005)) + list(np.arange(0.075, 0.500 + 1e-9, 0.025))
    lo = 0.0
    by_since = []
    for hi in edges:
        m = (s_b >= lo - 1e-9) & (s_b < hi - 1e-9)
        if m.any():
            by_since.append({"from": round(lo, 4), "to": round(hi, 4), **_share(big, m)})
        lo = hi
    by_tau = []
    for k in range(10):
        m = (tau[b] >= k * 0.05) & ((tau[b] < (k + 1) * 0.05) if k < 9 else np.isfinite(tau[b]))
        if m.any():
            by_tau.append({"from": round(k * 0.05, 3), "to": round((k + 1) * 0.05, 3) if k < 9 else None, **_share(big, m)})
    out["where"] = {"since_touchdown": by_since, "tau": by_tau}
    dank = np.abs(tq[b, 0] - tq[a, 0])
    dother = np.abs(tq[b, 1:] - tq[a, 1:]).max(1)
    deng = engaged_last[b] - engaged_last[a]
    topc = top_last[b] != top_last[a]
    swing = np.maximum(swing_mean[a], swing_mean[b])
    dzacc = np.abs(zacc[b] - zacc[a])

    def means(m):
        if not m.any():
            return None
        return {"pairs": int(m.sum()), "abs_dfz": float(np.abs(d[m]).mean()),
                "abs_d_tau_ankle": float(dank[m].mean()), "max_abs_d_tau_other": float(dother[m].mean()),
                "engaged_change_share": float(np.mean(deng[m] != 0)), "mean_abs_engaged_change": float(np.abs(deng[m]).mean()),
                "top_sphere_change_share": float(topc[m].mean()),
                "swing_loaded_share": float(np.mean(swing[m] > 0)), "swing_force_mean": float(swing[m].mean()),
                "abs_d_zacc": float(np.nanmean(dzacc[m])),
                "corr_dfz_d_tau_ankle": float(np.corrcoef(d[m], (tq[b, 0] - tq[a, 0])[m])[0, 1]) if m.sum() > 2 else None}
    out["with"] = {"large": means(big), "other": means(~big), "all": means(np.ones_like(big))}
    # hops: MuJoCo steps of a counted period in which no sphere of the stance foot carries a force
    kept_step_mask = np.isin(per, idx)
    hop_step = kept_step_mask & (stance_f.sum(1) == 0.0)
    hop_period = np.zeros(n_per, bool)
    hop_period[np.unique(per[hop_step])] = True
    near = hop_period[a] | hop_period[b] | hop_period[np.maximum(a - 1, 0)]
    out["hops"] = {"steps": int(hop_step.sum()), "periods": int(hop_period.sum()),
                   "counted_steps": int(kept_step_mask.sum()),
                   "large_near_hop_share": float(near[big].mean()) if big.any() else None,
                   "other_near_hop_share": float(near[~big].mean()) if (~big).any() else None}
    # alternation: the next pair in the same stance
    nxt = {int(x): i for i, x in enumerate(a)}
    lag, opp = [], []
    for i in range(len(d)):
        j = nxt.get(int(b[i]))
        if j is None:
            continue
        lag.append((d[i], d[j]))
        if big[i]:
            opp.append(bool(np.sign(d[j]) == -np.sign(d[i]) and abs(d[j]) > 0.5 * abs(d[i])))
    lag = np.array(lag)
    out["alternation"] = {"lag1_autocorr": float(np.corrcoef(lag[:, 0], lag[:, 1])[0, 1]) if len(lag) > 2 else None,
                          "large_followed_by_opposite_share": float(np.mean(opp)) if opp else None}
    # spectrum of the stance normal force per MuJoCo step, over the counted stretches
    fz_step = stance_f.sum(1)
    kept_step = kept_step_mask
    h = float(np.median(np.diff(pt)))
    spec = None
    segs = []
    cur = []
    for i in range(len(pt)):
        if kept_step[i] and (not cur or pst[i] == pst[cur[-1]]):
            cur.append(i)
        else:
            if len(cur) > 64:
                segs.append(cur)
            cur = [i] if kept_step[i] else []
    if len(cur) > 64:
        segs.append(cur)
    if segs:
        L = min(len(s) for s in segs)
        L = 2 ** int(np.floor(np.log2(L)))
        P = np.zeros(L // 2 + 1)
        for s in segs:
            x = fz_step[s[:L]] - fz_step[s[:L]].mean()
            P += np.abs(np.fft.rfft(x * np.hanning(L))) ** 2
        f = np.fft.rfftfreq(L, h)
        hf = f > 20.0
        k = int(np.argmax(np.where(hf, P, 0.0)))
        spec = {"window": L, "step": h, "peak_hz": float(f[k]), "peak_power_share_above_20hz": float(P[k] / P[hf].sum()),
                "power_share_above_250hz_of_above_20hz": float(P[f > 250.0].sum() / P[hf].sum())}
    out["spectrum"] = spec
    # the 12 largest pairs, for inspection
    order = np.argsort(-np.abs(d))[:12]
    out["largest"] = [{"t": float(t[b[i]]), "since": float(since[b[i]]), "tau": float(tau[b[i]]), "dfz": float(d[i]),
                       "d_tau_ankle": float(tq[b[i], 0] - tq[a[i], 0]), "engaged": [engaged_last[a[i]], engaged_last[b[i]]],
                       "top_sphere": [int(top_last[a[i]]), int(top_last[b[i]])], "swing_force": float(swing[i])}
                      for i in order]
    if trace:
        i = int(order[0])
        lo_t, hi_t = t[a[i]] - 0.003, t[b[i]] + 0.002
        rows = []
        for k in np.nonzero((pt > lo_t + 1e-9) & (pt <= hi_t + 1e-9))[0]:
            rows.append({"t_end": round(float(pt[k]), 6), "period_t": round(float(t[per[k]]), 6),
                         "tau_ankle": float(tq[per[k], 0]), "sphere_fz": [round(float(x), 2) for x in stance_f[k]],
                         "ankle_z_um": round(1e6 * float(probe.ankle_z[k]), 3),
                         "foot_pitch_rate": round(float(probe.pitch_rate[k]), 4)})
        out["largest_trace"] = rows
    return out


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--perturb", action="append", default=[], metavar="FIELD=VALUE")
    ap.add_argument("--threshold", type=float, default=200.0)
    ap.add_argument("--trace", action="store_true", help="add the MuJoCo steps around the largest pair")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    if a.steps < 1:
        ap.error(f"--steps must be >= 1, got {a.steps}")
    if a.threshold <= 0:
        ap.error(f"--threshold must be > 0 N, got {a.threshold}")
    run = provenance.Run(argv, plant="mujoco", profile="default",
                         command=".venv/bin/python -m lab.benchmarks.foot_tail " + " ".join(argv))
    r, probe = walk(a.steps, tuple(a.overrides), tuple(a.perturb))
    res = {"steps": a.steps, "overrides": a.overrides, "perturb": a.perturb, "quiet": measure(r)["overall"],
           "steps_walked": r.steps_walked, "fallen": r.fallen, **analyse(r, probe, a.threshold, a.trace)}
    text = json.dumps(res, indent=1)
    print(text)
    if a.json is not None:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(text + "\n", encoding="utf-8")
        run.record(a.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
