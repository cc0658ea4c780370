"""The training curve: one CSV row per PPO update (``results/<name>/curve.csv``, provenance beside it in
``run.json``) and its figure (``curve.png``), drawn from the file alone.

Columns (:data:`COLUMNS`): ``update``; ``env_steps`` (policy steps over all environments since the start of
training); ``wall_s`` (training wall time summed over the sittings [s]); ``segment`` (the sitting: 0 for the
first run, +1 per ``--resume``); ``episodes`` (episodes that ended during the update's rollout); over those
episodes ``return_mean``, ``length_mean`` [policy steps], ``duration_mean`` [s simulated], ``speed_mean`` (hip
x travelled / duration [m/s]), ``steps_walked_mean`` (touchdowns), ``fall_frac`` (the share that ended in a fall,
the rest in the time limit) and ``pushed_frac`` (the share that had a push); ``reward_mean`` (per policy step
over the rollout, all environments); ``policy_std`` (mean std of the Gaussian policy [torque / limit]);
``env_steps_per_s`` (the rollout's policy steps over its wall time, all environments); ``update_s`` (the PPO
update's wall time [s]). Episode columns are empty when no episode ended.

``python -m biped_controller.learning.curve results/ppo_baseline/curve.csv [--out PNG]`` redraws the figure and
writes ``curve_summary.json`` beside the CSV (:func:`summary`: the first, last and longest-episode rows, the
mean speeds of stepping and updating), with its provenance record when it is under ``results/``.
"""
from __future__ import annotations

import csv
import math
import sys
from pathlib import Path

COLUMNS = ("update", "env_steps", "wall_s", "segment", "episodes", "return_mean", "length_mean", "duration_mean",
           "speed_mean", "steps_walked_mean", "fall_frac", "pushed_frac", "reward_mean", "policy_std",
           "env_steps_per_s", "update_s")


class CurveError(ValueError):
    """A curve file that is missing or not in :data:`COLUMNS` (the message names it)."""


def read_curve(path: str | Path) -> list[dict[str, float]]:
    """The rows of a curve file, numbers as float (empty cells NaN)."""
    p = Path(path)
    if not p.is_file():
        raise CurveError(f"curve file {p}: no such file")
    with open(p, newline="") as f:
        r = csv.DictReader(f)
        if tuple(r.fieldnames or ()) != COLUMNS:
            raise CurveError(f"curve file {p}: columns {r.fieldnames}, expected {list(COLUMNS)}")
        return [{k: (float(v) if v not in ("", None) else math.nan) for k, v in row.items()} for row in r]


def write_curve(path: str | Path, rows: list[dict]) -> None:
    """Write ``rows`` (mappings over :data:`COLUMNS`; NaN or None written empty) to ``path`` atomically."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_suffix(p.suffix + ".tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for row in rows:
            cells = []
            for k in COLUMNS:
                v = row.get(k)
                if v is None or (isinstance(v, float) and math.isnan(v)):
                    cells.append("")
                elif isinstance(v, float):
                    cells.append(f"{v:.6g}")
                else:
                    cells.append(str(v))
            w.writerow(cells)
    tmp.replace(p)


def summary(rows: list[dict[str, float]]) -> dict:
    """The curve in a few numbers (for the guide's figures): ``updates``, ``first`` / ``last`` rows, ``best`` (the
    row with the longest mean episode), mean ``env_steps_per_s`` and ``update_s`` over the rows."""
    if not rows:
        raise CurveError("summary: the curve has no rows")
    clean = [{k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in r.items()} for r in rows]
    with_eps = [r for r in clean if r["length_mean"] is not None]
    best = max(with_eps, key=lambda r: r["length_mean"]) if with_eps else None
    return {"updates": len(rows), "first": clean[0], "last": clean[-1], "best": best,
            "env_steps_per_s_mean": sum(r["env_steps_per_s"] for r in rows) / len(rows),
            "update_s_mean": sum(r["update_s"] for r in rows) / len(rows)}


def draw(rows: list[dict[str, float]], out: str | Path, title: str = "") -> Path:
    """The curve figure: episode return, episode length and forward speed, and env steps/s, against env steps."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    x = [r["env_steps"] / 1e6 for r in rows]
    fig, ax = plt.subplots(2, 2, figsize=(10, 6.5), sharex=True)
    panels = ((ax[0, 0], "return_mean", "episode return (mean)"),
              (ax[0, 1], "length_mean", "episode length [policy steps] (mean)"),
              (ax[1, 0], "speed_mean", "forward speed over the episode [m/s] (mean)"),
              (ax[1, 1], "steps_walked_mean", "steps walked per episode (mean)"))
    for a, key, label in panels:
        a.plot(x, [r[key] for r in rows], lw=1.2)
        a.set_ylabel(label, fontsize=8)
        a.grid(alpha=0.3)
    segs = sorted({int(r["segment"]) for r in rows})
    for s in segs[1:]:
        first = next(r for r in rows if int(r["segment"]) == s)
        for a in ax.flat:
            a.axvline(first["env_steps"] / 1e6, color="0.6", ls=":", lw=0.8)
    for a in ax[1]:
        a.set_xlabel("environment steps [millions] (dotted: a resumed sitting)")
    if rows:
        last = rows[-1]
        fig.suptitle(f"{title}  {int(last['env_steps'])} env steps, {last['wall_s'] / 60:.1f} min wall, "
                     f"{int(last['update'])} updates", fontsize=9)
    fig.tight_layout()
    p = Path(out)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p


def main(argv: list[str] | None = None) -> int:
    from biped_controller.studies.trial.args import StudyArgumentParser
    ap = StudyArgumentParser(prog="curve", description="Draw a training curve (PNG) from its CSV file.")
    ap.add_argument("csv", help="the curve file (e.g. results/ppo_baseline/curve.csv)")
    ap.add_argument("--out", help="the PNG (default: curve.png beside the CSV)")
    ap.add_argument("--title", default="", help="the figure's title")
    a = ap.parse_args(argv)
    try:
        rows = read_curve(a.csv)
    except CurveError as exc:
        ap.error(str(exc))
    import json
    from biped_controller.studies.provenance import Run
    prov = Run(argv)
    out = draw(rows, a.out or Path(a.csv).with_suffix(".png"), a.title or Path(a.csv).parent.name)
    js = Path(a.csv).with_name(Path(a.csv).stem + "_summary.json")
    js.write_text(json.dumps(summary(rows), indent=1) + "\n", encoding="utf-8")
    if "results" in Path(a.csv).resolve().parts:
        prov.record(out, js)
    print(f"curve: {len(rows)} updates -> {out}, {js}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
