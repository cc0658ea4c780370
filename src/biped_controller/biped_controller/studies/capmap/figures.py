"""The map's PNG figures (matplotlib, Agg backend)."""
from __future__ import annotations

import math
import os
from pathlib import Path

from biped_controller.studies.capmap.driver import MapRun
from biped_controller.studies.capmap.search import Boundary
from biped_controller.studies.capmap.spec import Cell


_DIR_STYLE = {"forward": "-", "backward": "--"}
_MODE_COLOR = {"none": "0.4", "tau": "tab:blue", "p": "tab:orange", "both": "tab:green", "wbc": "tab:purple",
               "hybrid": "tab:red", "lambda": "tab:brown", "all": "tab:cyan"}
#: plug-in controllers (any other name): these colours in the order the map lists them
_PLUGIN_COLORS = ("tab:olive", "tab:pink", "black", "goldenrod", "teal")


def _color(m: str, modes) -> str:
    """The colour of mode or controller ``m`` among the map's ``modes``."""
    if m in _MODE_COLOR:
        return _MODE_COLOR[m]
    others = [x for x in modes if x not in _MODE_COLOR]
    return _PLUGIN_COLORS[others.index(m) % len(_PLUGIN_COLORS)]


def figures(run: MapRun, outdir: str | os.PathLike) -> list[Path]:
    """PNG figures: per mode the boundary vs onset phase (one panel per duration, both directions, right
    axis in N s), per mode a heat map of survival over (phase, force) on the coarse grid with the
    bisected boundary, and the four modes compared (one panel per direction and duration)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    s = run.spec
    paths: list[Path] = []

    def save(fig, name):
        p = out / name
        fig.tight_layout()
        fig.savefig(p, dpi=100)
        plt.close(fig)
        paths.append(p)

    nan = Boundary(math.nan, math.nan, ())

    def series(m, dr, du):
        ph = np.array(s.phases)
        bs = [run.boundaries.get(Cell(m, dr, x, du), nan) for x in s.phases]   # NaN: search incomplete
        return ph, np.array([b.lo for b in bs]), bs

    nd = len(s.durations)
    for m in s.modes:
        fig, axes = plt.subplots(1, nd, figsize=(max(4.2 * nd, 6.5), 3.6), squeeze=False)
        for ax, du in zip(axes[0], s.durations):
            for dr in s.directions:
                ph, f, bs = series(m, dr, du)
                ax.plot(ph, f, _DIR_STYLE[dr], marker="o", ms=3, label=dr)
                isl = [(x, y) for x, b in zip(ph, bs) for y in b.islands]
                if isl:
                    ax.plot(*zip(*isl), "x", color=ax.lines[-1].get_color(), ms=5, label=f"{dr} islands")
                cen = [(x, y) for x, y, b in zip(ph, f, bs) if b.hi is None]
                if cen:
                    ax.plot(*zip(*cen), "^", color=ax.lines[-1].get_color(), ms=6, label=f"{dr} censored")
            ax.set_title(f"{du:g} s push", fontsize=9)
            ax.set_xlabel("onset phase [fraction of the step]")
            ax.set_ylabel("largest survivable force [N]")
            sec = ax.secondary_yaxis("right", functions=(lambda F, d=du: F * d, lambda I, d=du: I / d))
            sec.set_ylabel("impulse [N s]")
            ax.set_xlim(-0.02, 1.0)
            ax.set_ylim(bottom=0)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
        fig.suptitle(f"mode {m}: survival boundary vs onset phase", fontsize=10)
        save(fig, f"boundary_{m}.png")

    nr = len(s.directions)
    dph = (s.phases[1] - s.phases[0]) if len(s.phases) > 1 else 1.0
    for m in s.modes:
        fig, axes = plt.subplots(nr, nd, figsize=(max(4.2 * nd, 6.5), 3.4 * nr), squeeze=False)
        for i, dr in enumerate(s.directions):
            for j, du in enumerate(s.durations):
                ax = axes[i][j]
                coarse = np.array(s.search.for_duration(du).coarse_forces())
                grid = np.full((len(coarse), len(s.phases)), np.nan)
                for k, x in enumerate(s.phases):
                    rc = run.records[Cell(m, dr, x, du)]
                    for r_i, F in enumerate(coarse):
                        if float(F) in rc:
                            grid[r_i, k] = 1.0 if rc[float(F)]["survived"] else 0.0
                ax.imshow(grid, origin="lower", aspect="auto", cmap="RdYlGn", vmin=0, vmax=1,
                          extent=(s.phases[0] - dph / 2, s.phases[-1] + dph / 2,
                                  coarse[0] - s.search.coarse / 2, coarse[-1] + s.search.coarse / 2),
                          interpolation="nearest")
                ph, f, _ = series(m, dr, du)
                ax.plot(ph, f, "k.-", lw=1, ms=3, label="boundary (bisected)")
                isl_top = max((y for x in s.phases for y in run.boundaries.get(Cell(m, dr, x, du), nan).islands),
                              default=0.0)
                top = max(float(np.nanmax(f, initial=0.0)) * 2.0, isl_top + 2 * s.search.coarse, 4 * s.search.coarse)
                ax.set_ylim(0, min(coarse[-1] + s.search.coarse / 2, top))
                ax.set_title(f"{dr}, {du:g} s", fontsize=9)
                ax.set_xlabel("onset phase")
                ax.set_ylabel("force [N]")
                ax.legend(fontsize=7, loc="upper right")
        fig.suptitle(f"mode {m}: survival (green) / failure (red) on the coarse grid", fontsize=10)
        save(fig, f"heatmap_{m}.png")

    fig, axes = plt.subplots(nr, nd, figsize=(max(4.2 * nd, 6.5), 3.4 * nr), squeeze=False)
    for i, dr in enumerate(s.directions):
        for j, du in enumerate(s.durations):
            ax = axes[i][j]
            for m in s.modes:
                ph, f, _ = series(m, dr, du)
                ax.plot(ph, f, marker="o", ms=3, color=_color(m, run.spec.modes), label=m)
            ax.set_title(f"{dr}, {du:g} s", fontsize=9)
            ax.set_xlabel("onset phase")
            ax.set_ylabel("largest survivable force [N]")
            ax.set_ylim(bottom=0)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
    fig.suptitle("adaptation modes compared: survival boundary vs onset phase", fontsize=10)
    save(fig, "modes.png")
    return paths
