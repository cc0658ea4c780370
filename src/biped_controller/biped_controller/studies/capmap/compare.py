"""Capability-map slices side by side: several map summaries (``scripts/capability_map --json``), one
duration, every controller and plant they hold, compared cell by cell.

Input: summaries as written by :func:`biped_controller.studies.capmap.findings.summary` (keys ``map``,
``settings``, ``boundaries``); each boundary record is one cell (mode, direction, onset phase, duration)
with ``force`` [N], the survival boundary (the largest force survived below the first failure), and,
when the map searched it, ``no_fall_edge`` [N], the largest force without a fall below the first fall.
The plant of a summary is its settings' ``plant`` (``settings.differs``), else ``default_plant``.

Per (plant, controller, direction), over the onset phases of the duration asked: the mean, the smallest
and the largest boundary [N] (with their phases), censored cells (survived up to the scan's top: their
force is a lower bound and enters the mean as such), the first failures' causes, and the cells whose
boundary lies within one bisection resolution (the summary's ``map.resolution`` [N]) of their no-fall
edge (``findings.no_fall_agreement``: ``no_fall_edge - force <= resolution``, or both censored).
Per (plant, direction, phase), the leader is the controller with the largest boundary (every
controller within ``tie`` [N] of the largest shares the lead); ``leads`` counts, per controller, the
phases it leads. Per pair of controllers (a, b) of a plant and direction, ``versus`` lists the phases
where a's boundary exceeds b's by more than one resolution, those where b's exceeds a's, and the rest
(equal to within the resolution). Every controller of a plant must have the same phases (else
:class:`CompareError`).
"""
from __future__ import annotations

from collections import Counter
from typing import Mapping, Sequence

from biped_controller.studies.capmap.findings import no_fall_agreement


class CompareError(ValueError):
    """A summary cannot be compared (the message names the file, the controller or the cell)."""


def plant_of(summ: Mapping, default_plant: str) -> str:
    """The plant a map summary was run on: ``settings.differs.plant``, else ``default_plant``."""
    differs = (summ.get("settings") or {}).get("differs") or {}
    return str(differs.get("plant", default_plant))


def cells(summaries: Sequence[tuple[str, Mapping]], duration: float, default_plant: str) -> dict:
    """``{(plant, controller, direction): {phase: boundary record}}`` of ``duration`` [s] over the
    summaries (``(name, summary)`` pairs; the name only labels errors). A cell given twice is an error."""
    out: dict[tuple[str, str, str], dict[float, dict]] = {}
    for name, summ in summaries:
        if "boundaries" not in summ:
            raise CompareError(f"{name}: not a capability-map summary (no 'boundaries')")
        plant = plant_of(summ, default_plant)
        for b in summ["boundaries"]:
            if abs(float(b["duration"]) - duration) > 1e-9:
                continue
            key = (plant, str(b["mode"]), str(b["direction"]))
            row = out.setdefault(key, {})
            ph = round(float(b["phase"]), 9)
            if ph in row:
                raise CompareError(f"{name}: cell {key} phase {ph:g} given twice")
            row[ph] = {**b, "resolution": float(summ["map"]["resolution"])}
    if not out:
        raise CompareError(f"no cell of duration {duration:g} s in {', '.join(n for n, _ in summaries)}")
    return out


def _row_stats(row: Mapping[float, dict]) -> dict:
    phases = sorted(row)
    forces = [float(row[p]["force"]) for p in phases]
    lo, hi = min(forces), max(forces)
    resolutions = {row[p]["resolution"] for p in phases}
    if len(resolutions) != 1:
        raise CompareError(f"one row's cells come from maps of different resolutions {sorted(resolutions)}")
    agree = no_fall_agreement([row[p] for p in phases], resolutions.pop())
    return {"phases": len(phases), "mean": sum(forces) / len(forces),
            "min": lo, "min_phases": [p for p, f in zip(phases, forces) if f == lo],
            "max": hi, "max_phases": [p for p, f in zip(phases, forces) if f == hi],
            "censored_phases": [p for p in phases if row[p].get("censored")],
            "causes": dict(sorted(Counter(str(row[p].get("cause") or "-") for p in phases).items())),
            "cells_with_no_fall_edge": agree.get("cells_with_no_fall_edge", 0),
            "cells_within_resolution_of_no_fall": agree.get("cells_boundary_within_resolution_of_no_fall", 0),
            "phases_below_no_fall": agree.get("phases_boundary_below_no_fall", []),
            # cells whose no-fall edge is undefined (a controller fault before any fall), only when there are some
            **({k: agree[k] for k in ("phases_no_fall_undefined",) if k in agree}),
            "boundaries": {f"{p:g}": float(row[p]["force"]) for p in phases}}


def compare(summaries: Sequence[tuple[str, Mapping]], duration: float, default_plant: str, tie: float = 0.0) -> dict:
    """The side-by-side comparison (module docstring) as a JSON-able dict."""
    if not tie >= 0:
        raise CompareError(f"tie must be >= 0 N, got {tie!r}")
    cs = cells(summaries, duration, default_plant)
    plants = list(dict.fromkeys(k[0] for k in cs))
    out: dict = {"duration": duration, "tie": tie, "plants": {}}
    for plant in plants:
        ctrls = list(dict.fromkeys(k[1] for k in cs if k[0] == plant))
        dirs = list(dict.fromkeys(k[2] for k in cs if k[0] == plant))
        stats: dict = {c: {} for c in ctrls}
        leads: dict = {d: {c: 0 for c in ctrls} for d in dirs}
        leaders: dict = {d: {} for d in dirs}
        for d in dirs:
            rows = {c: cs.get((plant, c, d)) for c in ctrls}
            missing = [c for c, r in rows.items() if r is None]
            if missing:
                raise CompareError(f"{plant}: {', '.join(missing)} has no {d} cells at {duration:g} s")
            phase_sets = {c: tuple(sorted(r)) for c, r in rows.items()}
            if len(set(phase_sets.values())) != 1:
                raise CompareError(f"{plant} {d}: the controllers' onset phases differ: "
                                   + "; ".join(f"{c} {len(p)} phases" for c, p in phase_sets.items()))
            for c in ctrls:
                stats[c][d] = _row_stats(rows[c])
            for ph in phase_sets[ctrls[0]]:
                best = max(float(rows[c][ph]["force"]) for c in ctrls)
                lead = [c for c in ctrls if best - float(rows[c][ph]["force"]) <= tie]
                leaders[d][f"{ph:g}"] = lead
                for c in lead:
                    leads[d][c] += 1
        versus = []
        for i, a in enumerate(ctrls):
            for b in ctrls[i + 1:]:
                entry: dict = {"a": a, "b": b}
                for d in dirs:
                    ra, rb = cs[(plant, a, d)], cs[(plant, b, d)]
                    res = max(ra[ph]["resolution"] for ph in ra)
                    diff = {f"{ph:g}": float(ra[ph]["force"]) - float(rb[ph]["force"]) for ph in sorted(ra)}
                    entry[d] = {"a_ahead": [k for k, v in diff.items() if v > res],
                                "b_ahead": [k for k, v in diff.items() if v < -res],
                                "equal": [k for k, v in diff.items() if abs(v) <= res],
                                "mean_difference": sum(diff.values()) / len(diff)}
                versus.append(entry)
        out["plants"][plant] = {"controllers": ctrls, "directions": dirs, "stats": stats, "leads": leads,
                                "leaders": leaders, "versus": versus}
    return out


def _phases(ps: Sequence[float]) -> str:
    return ", ".join(f"{p:g}" for p in ps) if ps else "-"


def markdown(cmp: Mapping) -> str:
    """The comparison as a markdown table: one row per (plant, controller), forward and backward mean,
    smallest boundary (its phases), phases led, and the no-fall agreement."""
    dirs = ("forward", "backward")
    head = ["plant", "controller"]
    for d in dirs:
        head += [f"{d}: mean [N]", f"{d}: min [N] (phase)", f"{d}: phases led"]
    head += ["boundary within one resolution step of the no-fall edge"]
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for plant, p in cmp["plants"].items():
        n_phases = None
        for c in p["controllers"]:
            cells_ = [plant, c]
            within = nf = undefined = 0
            for d in dirs:
                s = p["stats"][c].get(d)
                if s is None:
                    cells_ += ["-", "-", "-"]
                    continue
                n_phases = s["phases"]
                cens = f" ({len(s['censored_phases'])} censored)" if s["censored_phases"] else ""
                cells_ += [f"{s['mean']:.1f}{cens}", f"{s['min']:g} ({_phases(s['min_phases'])})",
                           f"{p['leads'][d][c]} of {n_phases}"]
                within += s["cells_within_resolution_of_no_fall"]
                nf += s["cells_with_no_fall_edge"]
                undefined += len(s.get("phases_no_fall_undefined", []))
            why = f"undefined in {undefined} (controller fault before any fall)" if undefined else ""
            cells_.append((f"{within} of {nf}" + (f"; {why}" if why else "")) if nf else why or "not searched")
            lines.append("| " + " | ".join(cells_) + " |")
    lines += ["", "| plant | a vs b | forward: phases a ahead / b ahead / equal (mean a - b [N]) | "
              "backward: phases a ahead / b ahead / equal (mean a - b [N]) |", "| --- | --- | --- | --- |"]
    for plant, p in cmp["plants"].items():
        for v in p["versus"]:
            row = [plant, f"{v['a']} vs {v['b']}"]
            for d in dirs:
                e = v.get(d)
                row.append("-" if e is None else f"{len(e['a_ahead'])} / {len(e['b_ahead'])} / {len(e['equal'])} "
                                                 f"({e['mean_difference']:+.1f})")
            lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)
