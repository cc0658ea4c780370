"""The headline table: the paper's cell for every mode on both plants, from the committed paper's-table files.

``python -m biped_controller.studies.headline`` prints the Markdown table that README.md and docs/paper_table.md
show, built from ``results/paper_table/{rigid,mujoco}_{paper,default}.json`` (each written by
``scripts/experiment table ... --json``; commands in ``results/paper_table/provenance.json``). A cell is the largest
push survived [N] (25 ms on the back at the paper's onset) under the survival rule; ``tests/test_headline.py``
checks that both documents hold exactly this table, so they cannot drift from the files.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from biped_model.settings import repo_root

#: the table's columns: (header, plant, profile)
COLUMNS = (("rigid, `paper`", "rigid", "paper"), ("rigid, `default`", "rigid", "default"),
           ("MuJoCo, `paper`", "mujoco", "paper"), ("MuJoCo, `default`", "mujoco", "default"))
#: the rows: (label, mode or controller name, the paper's published figure [N] or None: the "published" column)
ROWS = (("none (computed torque)", "none", None), ("tau", "tau", 455), ("p", "p", 320), ("both", "both", 650),
        ("wbc (whole-body QP)", "wbc", None), ("hybrid", "hybrid", None), ("lambda (torso)", "lambda", None),
        ("all (p, tau, lambda)", "all", None), ("capture_point (plug-in example)", "capture_point", None))


class HeadlineError(RuntimeError):
    """A paper's-table file is missing or lacks a row of the table."""


def table_file(plant: str, profile: str, root: Path | None = None) -> Path:
    return (root or repo_root()) / "results" / "paper_table" / f"{plant}_{profile}.json"


def load(root: Path | None = None) -> dict:
    """{(plant, profile): {mode: max_force [N]}} from the four files."""
    out = {}
    for _h, plant, profile in COLUMNS:
        path = table_file(plant, profile, root)
        try:
            modes = json.loads(path.read_text())["modes"]
        except (OSError, ValueError, KeyError) as exc:
            raise HeadlineError(f"{path}: cannot read its 'modes' ({exc})") from exc
        out[(plant, profile)] = {m: r["max_force"] for m, r in modes.items()}
    return out


def markdown(root: Path | None = None) -> str:
    """The table (Markdown, no trailing newline)."""
    data = load(root)
    lines = ["| mode | published | " + " | ".join(h for h, _p, _q in COLUMNS) + " |",
             "| --- | ---: | " + " | ".join("---:" for _ in COLUMNS) + " |"]
    for label, mode, paper in ROWS:
        cells = []
        for _h, plant, profile in COLUMNS:
            if mode not in data[(plant, profile)]:
                raise HeadlineError(f"{table_file(plant, profile, root)} has no row {mode!r}")
            cells.append(f"{data[(plant, profile)][mode]:g}")
        lines.append(f"| {label} | {'-' if paper is None else paper} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argparse.ArgumentParser(prog="python -m biped_controller.studies.headline",
                            description=__doc__.split("\n\n")[0]).parse_args(argv)
    try:
        print(markdown())
    except HeadlineError as exc:
        print(f"headline: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
