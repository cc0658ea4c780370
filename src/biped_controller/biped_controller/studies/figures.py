"""Figures of a robot's gait family (default robots/biped7/gait_family.json), written as PNG files.

Run through ``scripts/figures [--robot NAME|PATH] [--out DIR] [--family FILE]``: ``--robot`` the robot
(its description draws the links and the foot; its family, stamp-checked, unless ``--family``); ``--out``
default ``results/gait_family`` for the default robot, ``results/robots/<name>/gait_family`` for another:

  gait_stick_diagram.png   the preferred step (paper's Fig. 2): the links at 11 instants, stance foot
                           fixed at the origin, with the swing ankle's (and heel's and toe's) path
  gait_family_joints.png   q_i(t) of the fitted family for several strides p, with the optimised
                           strides' own polynomials dashed (the difference is the fit error)
  gait_zmp.png             centre of pressure l(t) = Gamma_1 / R_y of the preferred step (inverse
                           dynamics along q_d(p_d, t)), with the foot's +-0.1 m limits and the gait's
                           design margin

Pure Python (matplotlib with the Agg backend, Pinocchio through ``FixedFootModel``), deterministic.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin

from biped_model.description import load_description
from biped_model.settings import default_robot_dir, repo_root

from biped_model.gait_family import GaitFamily
from biped_model.fixed_foot import FixedFootModel
from biped_controller.studies import provenance


def posture_points(model: FixedFootModel, q: np.ndarray) -> dict[str, np.ndarray]:
    """World (x, z) of the stance ankle, knees, hip, swing ankle, torso top, and both feet's heel/toe,
    with the stance ankle at the origin and the stance foot flat."""
    m = model.model
    d = model.data
    x = np.zeros(9)
    x[3:] = q
    pin.forwardKinematics(m, d, x)
    pos = {}
    names = {"ankle_st": "q1_stance_ankle", "knee_st": "q2_stance_knee", "hip": "q3_stance_hip",
             "knee_sw": "q5_swing_knee", "ankle_sw": "q6_swing_ankle"}
    for k, n in names.items():
        t = d.oMi[m.getJointId(n)].translation
        pos[k] = np.array([t[0], t[2]])
    torso = d.oMi[m.getJointId("q3_stance_hip")].act(np.array([0.0, 0.0, model.desc.torso.length]))
    pos["head"] = np.array([torso[0], torso[2]])
    ft = model.desc.foot
    ang = float(np.sum(q))  # absolute swing foot angle (ccw)
    c, s = np.cos(ang), np.sin(ang)
    pos["heel_sw"] = pos["ankle_sw"] + ft.l_min * np.array([c, s])
    pos["toe_sw"] = pos["ankle_sw"] + ft.l_max * np.array([c, s])
    pos["heel_st"] = np.array([ft.l_min, 0.0])
    pos["toe_st"] = np.array([ft.l_max, 0.0])
    return pos


def stick_diagram(fam: GaitFamily, model: FixedFootModel, path: Path, instants: int = 11) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 6.2))
    cmap = plt.get_cmap("viridis")
    for k, t in enumerate(np.linspace(0.0, fam.T, instants)):
        P = posture_points(model, fam.evaluate(fam.p_d, t).q)
        col = cmap(k / (instants - 1))
        stance = np.array([P["ankle_st"], P["knee_st"], P["hip"]])
        swing = np.array([P["hip"], P["knee_sw"], P["ankle_sw"]])
        ax.plot(stance[:, 0], stance[:, 1], "-", color=col, lw=2.2)
        ax.plot(swing[:, 0], swing[:, 1], "--", color=col, lw=1.6)
        ax.plot([P["hip"][0], P["head"][0]], [P["hip"][1], P["head"][1]], "-", color=col, lw=3.0)
        ax.plot([P["heel_sw"][0], P["toe_sw"][0]], [P["heel_sw"][1], P["toe_sw"][1]], "-", color=col, lw=1.2)
        ax.plot(*P["hip"], "o", color=col, ms=3)
    ts = np.linspace(0.0, fam.T, 300)
    path_pts = [posture_points(model, fam.evaluate(fam.p_d, t).q) for t in ts]
    for key, style, label in (("ankle_sw", "r-", "swing ankle path"), ("heel_sw", "r:", "swing heel / toe"),
                              ("toe_sw", "r:", None)):
        xy = np.array([p[key] for p in path_pts])
        ax.plot(xy[:, 0], xy[:, 1], style, lw=1.0, label=label)
    ft = model.desc.foot
    ax.plot([ft.l_min, ft.l_max], [0, 0], "k-", lw=4, solid_capstyle="butt", label="stance foot")
    ax.axhline(0.0, color="0.3", lw=0.8)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m] (from the stance ankle)")
    ax.set_ylabel("z [m]")
    ax.set_title(f"Preferred step: p_d = {fam.p_d} m, T = {fam.T} s ({instants} instants, dark = t = 0; "
                 "solid: stance leg, dashed: swing leg)", fontsize=8.5)
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(0, fam.T))
    fig.colorbar(sm, ax=ax, label="t [s]", shrink=0.7)
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def family_joints(fam: GaitFamily, path: Path, strides: list[float] | None = None) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    records = {round(r["stride"], 6): r for r in fam.meta.get("strides", [])}
    if strides is None:
        cand = [fam.p_min, 0.4, fam.p_d, 0.55, fam.p_max]
        strides = [p for p in cand if fam.p_min <= p <= fam.p_max]
    ts = np.linspace(0.0, fam.T, 200)
    names = ("q1 stance ankle", "q2 stance knee", "q3 stance hip", "q4 swing hip", "q5 swing knee", "q6 swing ankle")
    fig, axes = plt.subplots(3, 2, figsize=(9, 8.5), sharex=True)
    cmap = plt.get_cmap("plasma")
    for n, p in enumerate(strides):
        col = cmap(n / max(len(strides) - 1, 1) * 0.9)
        Q = np.array([fam.evaluate(p, t).q for t in ts])
        rec = records.get(round(p, 6))
        Qo = None
        if rec is not None:
            a = np.array(rec["a"])
            Qo = np.array([a @ (t ** np.arange(a.shape[1])) for t in ts])
        for i, ax in enumerate(axes.T.ravel()):
            ax.plot(ts, Q[:, i], color=col, lw=1.4, label=f"p = {p:.3f} m" + (" (p_d)" if p == fam.p_d else ""))
            if Qo is not None:
                ax.plot(ts, Qo[:, i], color=col, lw=0.9, ls="--")
    for i, ax in enumerate(axes.T.ravel()):
        ax.set_title(names[i], fontsize=9)
        ax.set_ylabel("[rad]")
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("tau [s]")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("Gait family q_d(p, tau): fitted b_ijk (solid) and the optimised strides' own polynomials (dashed)",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def preferred_zmp(fam: GaitFamily, model: FixedFootModel, n: int = 400) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, l(t), R_y(t)) along q_d(p_d, t) with tau' = 1 (inverse dynamics of the fixed-foot model)."""
    ts = np.linspace(0.0, fam.T, n + 1)
    l, ry = np.empty_like(ts), np.empty_like(ts)
    for k, t in enumerate(ts):
        q, qd, qdd = fam.reference(fam.p_d, 0.0, t, 1.0)
        gam, r = model.inverse_dynamics(q, qd, qdd)
        l[k], ry[k] = gam[0] / r[1], r[1]
    return ts, l, ry


def zmp_figure(fam: GaitFamily, model: FixedFootModel, path: Path) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ts, l, _ = preferred_zmp(fam, model)
    ft = model.desc.foot
    margin = fam.meta.get("settings", {}).get("zmp_margin", {}).get("value")
    fig, ax = plt.subplots(figsize=(7, 3.6))
    ax.plot(ts, l, lw=1.4, label="l(t) = Gamma_1 / R_y")
    ax.axhline(ft.l_max, color="k", ls="--", lw=0.9, label="foot limits (toe / heel)")
    ax.axhline(ft.l_min, color="k", ls="--", lw=0.9)
    if margin is not None:
        ax.axhline(ft.l_max - margin, color="0.5", ls=":", lw=0.9, label=f"design margin ({margin} m)")
        ax.axhline(ft.l_min + margin, color="0.5", ls=":", lw=0.9)
    ax.set_ylim(1.25 * ft.l_min, 1.25 * ft.l_max)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("l [m] (+ toward the toe)")
    ax.set_title(f"Centre of pressure of the preferred step (p_d = {fam.p_d} m): max |l| = {np.max(np.abs(l)):.4f} m",
                 fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def make_all(out: Path, family: Path | None = None, robot: str | None = None) -> list[Path]:
    """The three figures of ``robot``'s family (or of the family file ``family``, drawn with ``robot``'s
    description; None: the default robot) into ``out``."""
    if robot is None:
        fam, desc = GaitFamily.load(family), load_description()
    else:
        from biped_model.robot import resolve_robot
        r = resolve_robot(robot)
        desc = r.description()
        fam = GaitFamily.load(family) if family is not None else r.family()
    model = FixedFootModel(desc)
    out.mkdir(parents=True, exist_ok=True)
    return [stick_diagram(fam, model, out / "gait_stick_diagram.png"),
            family_joints(fam, out / "gait_family_joints.png"),
            zmp_figure(fam, model, out / "gait_zmp.png")]


def main(argv: list[str] | None = None) -> int:
    from biped_controller.studies.trial.args import StudyArgumentParser
    ap = StudyArgumentParser(prog="scripts/figures", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robot", default=None, metavar="NAME|PATH",
                    help="the robot: a name under robots/ or a robot directory (default biped7; docs/robots.md)")
    ap.add_argument("--out", type=Path, default=None,
                    help="default results/gait_family (default robot), results/robots/<name>/gait_family (another)")
    ap.add_argument("--family", type=Path, default=None, help="a family file (default the robot's)")
    args = ap.parse_args(argv)
    from biped_model.robot import RobotError, resolve_robot
    try:
        r = resolve_robot(args.robot)
        r.description()
        if args.family is None:
            r.check_stamp()
    except RobotError as exc:
        ap.error(str(exc))
    robot = None if r.is_default else str(r.directory)
    if args.family is None and robot is None:
        args.family = default_robot_dir() / "gait_family.json"
    if args.out is None:
        args.out = repo_root() / "results" / ("gait_family" if robot is None else f"robots/{r.name}/gait_family")
    provenance.track(args.out, args=args, argv=argv)   # record of each file written (results/README.md)
    for p in make_all(args.out, args.family, robot):
        print(p)
    return 0


if __name__ == "__main__":
    sys.exit(main())
