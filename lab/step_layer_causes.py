"""What the DCM step layer of ``dcm_wbc`` compares the measured DCM with: one variant that changes only that.

Question (docs/step_layer.md, "Why the first law lost"): ``dcm_wbc`` (its first law) falls two to three steps after a push it has
survived, with its DCM error growing from step to step. Is the cause that the layer compares the measured DCM
xi [m] with the *preferred* step's DCM xi_n(tau) (the table along q_d(p_d, .) at tau' = 1), while its own
outputs p and tau' change the reference's speed, so that the layer reads its own command as a DCM error?

:class:`CommandedDcm` is ``dcm_wbc`` with that one thing changed: the DCM it compares xi with (in the dead band,
the step location law and the reported ``dcm_error``) is the DCM of the reference it commands,

    xi_r = x_r + x_r' / omega,   x_r = x_G(q_d(p, tau)),   x_r' = J_G(q_d) (dq/dp p' + dq/dtau tau')   [m],

at the period's p [m], p' [m/s], tau [s] (held to [0, T]) and tau' [-]; with p = p_d, tau' = 1 it is xi_n(tau).
Everything else (omega, the offset law, the timing, the gains, the whole-body QP, the observer, the settings)
is ``dcm_wbc``'s. The product adopted this law after the first map (``step_layer_commanded_dcm: true``,
``plugin.step_layer.DcmStepLayer.reference_dcm``; the same pushed run gives the same record to the last digit,
docs/step_layer.md): this class stays as the record of the runs under ``results/step_layer/causes/``, and
``--option commanded_dcm=false`` of ``dcm_wbc`` is now the first law. Run it by its ``module:Class`` name from the repository root, e.g.

    .venv/bin/python -m biped_controller.studies.controllers max-push lab.step_layer_causes:CommandedDcm --max 800 \\
        --json results/step_layer/causes/commanded_dcm_paper_cell_rigid.json
"""
from __future__ import annotations

import sys

from biped_controller.plugin.step_layer import DcmStepLayer, DcmWholeBody


class _CommandedLayer(DcmStepLayer):
    """The layer with xi_n(tau) replaced by the commanded reference's DCM at the controller's (p, p', tau')."""

    ctrl: "CommandedDcm"

    def xi_n(self, tau: float) -> float:
        c = self.ctrl
        g = self.ref.at(c.p, min(max(float(tau), 0.0), self.T))
        st = c.model.com_state(g.q, g.dq_dp * c.p_dot + g.dq_dtau * c.tau_dot)
        return float(st.position[0] + st.velocity[0] / self.omega)


class CommandedDcm(DcmWholeBody):
    """``dcm_wbc`` whose DCM error is measured against the commanded reference's DCM (module docstring)."""

    description = "dcm_wbc with the DCM error taken against the commanded reference's DCM (lab.step_layer_causes)"

    def __init__(self, setup):
        super().__init__(setup)
        lay = self.layer
        self.layer = _CommandedLayer.__new__(_CommandedLayer)
        self.layer.__dict__.update(lay.__dict__)
        self.layer.ctrl = self


# ---------------------------------------------------------------------------------------------------------- cells
def cell_table(slices: dict, subject: str, against: tuple[str, ...], extra: dict[str, dict] | None = None,
               tie: float = 5.0, label: str | None = None) -> dict:
    """Cell by cell (plant, direction, onset phase): the boundary [N] of ``subject`` and of each controller of
    ``against`` from a ``controllers slices`` JSON (``plants/<plant>/stats/<name>/<direction>/boundaries``), and
    subject - other [N]; ``extra``: name -> {plant: capability-map summary} of a variant measured at some of the
    phases (its ``boundaries`` rows), with variant - other where it was measured. A controller missing on a plant
    is left out of that plant; ``extra_stats``: :func:`extra_stats` of each variant (``tie`` [N]). ``label``: the
    name the subject's column goes by (default its name; e.g. ``first_law`` when a variant of the same name is
    an extra)."""
    col = label or subject
    out = {"subject": col, "against": list(against), "extra": sorted(extra or {}), "plants": {}}
    for plant, pdata in slices["plants"].items():
        stats = pdata["stats"]
        if subject not in stats:
            continue
        names = [a for a in against if a in stats]
        rows = []
        for direction in pdata["directions"]:
            bounds = stats[subject][direction]["boundaries"]
            for phase, force in bounds.items():
                row = {"direction": direction, "phase": float(phase), col: force}
                for a in names:
                    other = stats[a][direction]["boundaries"].get(phase)
                    row[a] = other
                    row[f"{col} - {a}"] = None if other is None or force is None else force - other
                for name, maps in (extra or {}).items():
                    summary = maps.get(plant)
                    hit = [b for b in (summary or {}).get("boundaries", [])
                           if b["direction"] == direction and abs(b["phase"] - float(phase)) < 1e-9]
                    v = hit[0]["force"] if hit else None
                    row[name] = v
                    for a in [col] + names:
                        ref = row[a]
                        row[f"{name} - {a}"] = None if v is None or ref is None else v - ref
                rows.append(row)
        out["plants"][plant] = {"rows": rows}
    out["extra_stats"] = {name: extra_stats(out, name, [col] + list(against), tie) for name in sorted(extra or {})}
    return out


def extra_stats(table: dict, name: str, others: list[str], tie: float = 5.0) -> dict:
    """Over the cells where the variant ``name`` was measured, per plant and direction: ``cells`` (how many,
    and their phases), ``mean`` [N] of the variant and of each controller of ``others`` over the same cells
    (``means``), and per other ``a``: ``ahead`` / ``behind`` / ``equal`` = cells where the variant is ahead by
    more than ``tie`` [N] / behind by more than ``tie`` / within it, ``mean_difference`` [N] = mean of variant - a.
    A controller missing in a measured cell is left out of that plant's comparison."""
    out: dict = {}
    for plant, pdata in table["plants"].items():
        for direction in sorted({r["direction"] for r in pdata["rows"]}):
            rows = [r for r in pdata["rows"] if r["direction"] == direction and r.get(name) is not None]
            if not rows:
                continue
            entry = {"cells": len(rows), "phases": [r["phase"] for r in rows],
                     "mean": sum(r[name] for r in rows) / len(rows), "means": {}, "versus": {}}
            for a in others:
                if any(r.get(a) is None for r in rows):
                    continue
                d = [r[name] - r[a] for r in rows]
                entry["means"][a] = sum(r[a] for r in rows) / len(rows)
                entry["versus"][a] = {"ahead": sum(x > tie for x in d), "behind": sum(x < -tie for x in d),
                                      "equal": sum(abs(x) <= tie for x in d), "mean_difference": sum(d) / len(d)}
            out.setdefault(plant, {})[direction] = entry
    return out


def stats_markdown(table: dict) -> str:
    """The variants' cell-subset means and leads as one markdown table."""
    lines = []
    for name, plants in table.get("extra_stats", {}).items():
        lines.append(f"{name}, over the cells where it was measured (mean [N]; cells {name} ahead / behind / "
                     "within 5 N, mean difference [N]):\n")
        lines.append("| plant | direction | cells | " + name + " | controller | its mean | ahead / behind / equal | "
                     f"mean {name} - it |")
        lines.append("| --- | --- | ---: | ---: | --- | ---: | --- | ---: |")
        for plant, dirs in plants.items():
            for direction, e in dirs.items():
                for a, v in e["versus"].items():
                    lines.append(f"| {plant} | {direction} | {e['cells']} | {e['mean']:.1f} | {a} | "
                                 f"{e['means'][a]:.1f} | {v['ahead']} / {v['behind']} / {v['equal']} | "
                                 f"{v['mean_difference']:+.1f} |")
        lines.append("")
    return "\n".join(lines)


class MapMergeError(ValueError):
    """Two maps of one variant disagree at a cell they both measured."""


def merge_maps(a: dict, b: dict) -> dict:
    """The ``boundaries`` of two capability-map summaries of one controller on one plant measured on different
    onset grids (e.g. 4 and 10 phases), as one summary {"boundaries": [...]}; a cell (direction, phase) in both
    must have the same boundary, else :class:`MapMergeError`."""
    cells: dict = {}
    for b_ in list(a.get("boundaries", [])) + list(b.get("boundaries", [])):
        key = (b_["direction"], round(float(b_["phase"]), 9))
        if key in cells and cells[key]["force"] != b_["force"]:
            raise MapMergeError(f"{key[0]} onset {key[1]:g}: {cells[key]['force']} N in one map, {b_['force']} N in the other")
        cells.setdefault(key, b_)
    return {"boundaries": [cells[k] for k in sorted(cells)]}


def cell_markdown(table: dict) -> str:
    """The cell table as one markdown table per plant (N; '-' where not measured)."""
    subject, against, extra = table["subject"], table["against"], table["extra"]
    lines = []
    for plant, pdata in table["plants"].items():
        cols = [subject] + against + [f"{subject} - {a}" for a in against]
        for name in extra:
            cols += [name] + [f"{name} - {a}" for a in [subject] + against]
        lines.append(f"{plant}:\n")
        lines.append("| direction | phase | " + " | ".join(cols) + " |")
        lines.append("| --- | ---: | " + " | ".join("---:" for _ in cols) + " |")
        for r in pdata["rows"]:
            vals = ["-" if r.get(c) is None else f"{r[c]:+g}" if " - " in c else f"{r[c]:g}" for c in cols]
            lines.append(f"| {r['direction']} | {r['phase']:g} | " + " | ".join(vals) + " |")
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> int:
    """``cells SLICES.json [--extra NAME=PLANT:MAP.json ...] --json F --markdown F``: :func:`cell_table`."""
    import argparse
    import json
    from pathlib import Path

    from biped_controller.studies import provenance
    ap = argparse.ArgumentParser(prog="python -m lab.step_layer_causes", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("cells", help="cell-by-cell boundaries and differences from a controllers-slices JSON")
    c.add_argument("slices", type=Path)
    c.add_argument("--subject", default="dcm_wbc")
    c.add_argument("--label", help="the subject's column name (default its name)")
    c.add_argument("--against", nargs="+", default=["wbc", "both"])
    c.add_argument("--extra", action="append", default=[],
                   help="NAME=PLANT:MAP.json (repeatable; maps of one NAME and PLANT on different onset grids merge)")
    c.add_argument("--json", type=Path)
    c.add_argument("--markdown", type=Path)
    args = ap.parse_args(argv)
    provenance.track(args.json, args.markdown, argv=argv)
    try:
        slices = json.loads(args.slices.read_text(encoding="utf-8"))
        extra: dict[str, dict] = {}
        for e in args.extra:
            name, _, rest = e.partition("=")
            plant, _, path = rest.partition(":")
            if not (name and plant and path):
                ap.error(f"--extra {e!r}: expected NAME=PLANT:MAP.json")
            summary = json.loads(Path(path).read_text(encoding="utf-8"))
            have = extra.setdefault(name, {})
            have[plant] = merge_maps(have[plant], summary) if plant in have else summary
    except (OSError, ValueError) as exc:          # MapMergeError is a ValueError
        ap.error(str(exc))
    if "plants" not in slices:
        ap.error(f"{args.slices}: not a controllers-slices JSON (no 'plants')")
    table = cell_table(slices, args.subject, tuple(args.against), extra, label=args.label)
    text = cell_markdown(table) + ("\n" + stats_markdown(table) if extra else "")
    print(text)
    for path, body in ((args.json, json.dumps(table, indent=1) + "\n"), (args.markdown, text)):
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(body, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
