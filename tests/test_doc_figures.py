"""Every figure marker in README.md and docs/*.md holds against its results file (tests/doc_figures.py), and the
check sees a changed figure, a missing key and a marker without a figure."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

import doc_figures as df

ROOT = Path(__file__).resolve().parents[1]
#: the reports (the README's "Reports" list): each carries markers on its findings' figures
REPORTS = ("paper_table", "paper_method", "mujoco_plant", "baseline_wbc", "torso_parameter", "robustness",
           "capability_map", "gait_family_range", "step_layer")


def test_every_marker_holds():
    markers, problems = df.check(ROOT)
    assert not problems, "figures that differ from their files:\n" + "\n".join(problems)
    assert markers


@pytest.mark.parametrize("doc", ["README.md"] + [f"docs/{r}.md" for r in REPORTS])
def test_the_readme_and_every_report_carry_markers(doc):
    assert df.parse((ROOT / doc).read_text(encoding="utf-8"), doc), f"{doc} has no figure marker"


def _copy(tmp_path: Path, markers: list[df.Marker]) -> Path:
    """README.md, docs/*.md and every results file a marker names, under tmp_path."""
    for p in df.documents(ROOT):
        (tmp_path / p.relative_to(ROOT)).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(p, tmp_path / p.relative_to(ROOT))
    for path in {m.path for m in markers}:
        (tmp_path / path).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / path, tmp_path / path)
    return tmp_path


def test_a_changed_committed_figure_fails_the_check(tmp_path):
    """Negative control: change the figure one marker reads (in a copy of its results file) and the check names
    that document line; restore it and the check passes."""
    markers, _ = df.check(ROOT)
    root = _copy(tmp_path, markers)
    target = next(m for m in markers if m.path == "results/paper_table/maps_25ms.json"
                  and m.query == "/plants/rigid/stats/tau/backward/max")
    path = root / target.path
    original = path.read_text(encoding="utf-8")
    data = json.loads(original)
    data["plants"]["rigid"]["stats"]["tau"]["backward"]["max"] += 3.125
    path.write_text(json.dumps(data), encoding="utf-8")
    _, problems = df.check(root)
    assert any(p.startswith(f"{target.doc}:{target.line}: {target.figure} <-") for p in problems), problems
    path.write_text(original, encoding="utf-8")
    assert df.check(root)[1] == []


def test_the_figure_is_the_last_number_before_the_marker():
    text = ("a 4467 simulations in 120.0 s <!-- fig: r.json#/a -->\n"
            "range 11.4-78.4 s <!-- fig: r.json#/b -->, a minus -3.5 <!-- fig: r.json#/c scale=-1 -->\n"
            "p_d = 0.463 m<!-- fig: r.json#/d fmt=.3f -->, within 6.4e-4 rad <!-- fig: r.json#/e -->\n")
    ms = df.parse(text, "x.md")
    assert [(m.line, m.figure) for m in ms] == [(1, "120.0"), (2, "78.4"), (2, "-3.5"), (3, "0.463"), (3, "6.4e-4")]
    assert ms[2].scale == -1.0 and ms[3].fmt == ".3f"


def test_a_marker_in_code_is_an_example():
    text = ("syntax `<!-- fig: FILE#/a -->`\n```\n5 <!-- fig: r.json#/b -->\n```\n7 N <!-- fig: r.json#/c -->\n")
    assert [(m.line, m.figure, m.query) for m in df.parse(text, "x.md")] == [(5, "7", "/c")]


def test_queries_select_filter_and_aggregate():
    doc = {"rows": [{"mode": "tau", "phase": 0.5, "force": 362.5}, {"mode": "tau", "phase": 0.95, "force": 137.5},
                    {"mode": "both", "phase": 0.5, "force": 553.125}],
           "keys": {"0.05": 1.25, "a/b": 2}}
    assert df.resolve(doc, "/rows/[mode=tau,phase=0.50]/force") == 362.5
    assert df.resolve(doc, "/rows/[mode=tau]/force|mean") == 250.0
    assert df.resolve(doc, "/rows/*/force|max") == 553.125
    assert df.resolve(doc, "/rows/[mode=tau]|len") == 2
    assert df.resolve(doc, "/keys/0.05") == 1.25 and df.resolve(doc, "/keys/a~1b") == 2
    assert df.resolve(doc, "/rows/2/force") == 553.125
    for bad, why in (("/rows/[mode=tau]/force", "selects 2 values"), ("/rows/9/force", "no key '9'"),
                     ("/keys/x", "no key 'x'"), ("/rows/0/mode", "not a number"), ("rows", "must start"),
                     ("/rows/*/force|median", "unknown operation")):
        with pytest.raises(df.MarkerError, match=why):
            df.resolve(doc, bad)


def test_rounding_and_formats():
    assert df.matches("696.4", 696.4375) and df.matches("0.2560", 0.256) and df.matches("4467", 4467)
    assert not df.matches("0.2555", 0.256) and not df.matches("4183", 4467) and not df.matches("696.5", 696.4375)
    assert df.matches("15.4", 15.43, ".1f") and not df.matches("15.40", 15.43, ".1f")
    assert df.matches("6.4e-4", 6.38e-4) and not df.matches("6.4e-4", 6.3e-4) and df.matches("2e3", 2049)


def test_a_marker_without_a_figure_or_a_file_is_reported(tmp_path):
    with pytest.raises(df.MarkerError, match="no figure"):
        df.parse("none here <!-- fig: r.json#/a -->", "x.md")
    with pytest.raises(df.MarkerError, match="PATH#QUERY"):
        df.parse("3 <!-- fig: r.json -->", "x.md")
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "x.md").write_text("7 N <!-- fig: results/none.json#/a -->\n")
    _, problems = df.check(tmp_path)
    assert problems and problems[0].startswith("docs/x.md:1: 7 <- results/none.json#/a: cannot read")
