"""Results and the documents that cite them: every repository path README.md, DESIGN.md, docs/*.md and
lab/README.md cite exists, every file under results/ has a complete provenance record, and benchmarks/ holds code only.

A cited path is a markdown link's target (relative to the document) or a token of inline code or of a
fenced code block starting with a top-level directory of the repository (``results/``, ``docs/``, ``benchmarks/``, ``lab/``, ``src/``, ``config/``,
``scripts/``, ``tests/``). ``{a,b}`` alternatives are expanded; ``*``, ``<name>`` and a lone capital letter between separators
(``table_P_observer_O.json``: placeholders) match any name, and at least one file must match.
``git show COMMIT:PATH`` cites a file of the history: that object must exist.
"""
from __future__ import annotations

import itertools
import re
import subprocess
from pathlib import Path

import pytest

from biped_controller.studies.provenance import FIELDS, PROVENANCE_FILE, UNKNOWN, read_records

ROOT = Path(__file__).resolve().parents[1]
TOP = ("results/", "docs/", "benchmarks/", "lab/", "src/", "config/", "scripts/", "tests/")
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
CODE = re.compile(r"`([^`\n]+)`")
GIT_SHOW = re.compile(r"git show ([0-9a-f]{7,40}):(\S+)")
PLACEHOLDER = re.compile(r"(?<=[_/])[A-Z](?=[_.])")


def documents(root: Path = ROOT) -> list[Path]:
    return [p for p in (root / "README.md", root / "DESIGN.md") if p.exists()] + sorted((root / "docs").glob("*.md")) \
        + [p for p in (root / "lab" / "README.md",) if p.exists()]


def _expand(path: str) -> list[str]:
    """``a{b,c}d`` -> ``abd``, ``acd`` (every brace group, in order)."""
    parts = re.split(r"(\{[^{}]*\})", path)
    choices = [p[1:-1].split(",") if p.startswith("{") and p.endswith("}") else [p] for p in parts]
    return ["".join(c) for c in itertools.product(*choices)]


def _exists(root: Path, rel: str) -> bool:
    """A path (file or directory) exists, a glob matches, a module path names ``X.py`` (``pkg/mod``,
    ``pkg/mod.attr``), or a pytest node ``file.py::name`` names a function or class defined in the file."""
    if "::" in rel:
        rel, node = rel.split("::", 1)
        name = node.split("::")[-1].split("[")[0]
        p = root / rel
        return p.is_file() and re.search(rf"^\s*(?:async\s+)?(?:def|class)\s+{re.escape(name)}\b",
                                         p.read_text(encoding="utf-8"), re.M) is not None
    rel = rel.rstrip("/")
    pattern = PLACEHOLDER.sub("*", re.sub(r"<[^<>/]+>", "*", rel))
    if any(ch in pattern for ch in "*?["):
        return any(root.glob(pattern))
    p = root / rel
    if p.exists():
        return True
    mod = re.sub(r"\.[A-Za-z_]\w*$", "", rel)
    return (root / f"{mod}.py").exists() or (root / f"{rel}.py").exists()


def _git_object(root: Path, commit: str, path: str) -> bool:
    try:
        return subprocess.run(["git", "cat-file", "-e", f"{commit}:{path}"], cwd=root, capture_output=True,
                              check=False).returncode == 0
    except OSError:
        pytest.skip("git is not available")


def cited_paths(doc: Path, root: Path = ROOT) -> list[tuple[int, str, str]]:
    """(line, as written, repository-relative path) of every path ``doc`` cites; ``git show`` citations
    come back as ``COMMIT:PATH``."""
    out = []
    fenced = False
    for n, line in enumerate(doc.read_text(encoding="utf-8").splitlines(), 1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        spans = [line] if fenced else [m.group(1) for m in CODE.finditer(line)]
        for m in LINK.finditer("" if fenced else line):
            target = m.group(1).split("#", 1)[0]
            if not target or re.match(r"[a-z][a-z0-9+.-]*:", target):     # URL, mailto:, anchor-only
                continue
            rel = (doc.parent / target).resolve()
            try:
                out.append((n, target, str(rel.relative_to(root))))
            except ValueError:
                out.append((n, target, str(rel)))                           # outside the repository
        for span in spans:
            for g in GIT_SHOW.finditer(span):
                out.append((n, g.group(0), f"{g.group(1)}:{g.group(2)}"))
            span = GIT_SHOW.sub(" ", span)
            for tok in re.split(r"[\s=();]+|,(?![^{]*\})", span):
                tok = re.sub(r":\d+(-\d+)?$", "", tok.strip("'\".,;:"))
                if tok.startswith(TOP) and not tok.startswith(("src/...", "results/<")):
                    out.append((n, tok, tok))
    return out


def broken_citations(root: Path = ROOT) -> list[str]:
    bad = []
    for doc in documents(root):
        for n, written, rel in cited_paths(doc, root):
            m = re.fullmatch(r"([0-9a-f]{7,40}):(.+)", rel)
            ok = _git_object(root, *m.groups()) if m else all(_exists(root, r) for r in _expand(rel))
            if not ok:
                bad.append(f"{doc.relative_to(root)}:{n}: {written}")
    return bad


def test_every_cited_path_exists():
    bad = broken_citations()
    assert not bad, f"{len(bad)} cited paths do not exist:\n" + "\n".join(bad)


def test_a_broken_citation_is_found(tmp_path):
    """The check itself: a link to a missing file, a missing backticked path, a brace alternative that
    does not exist and a ``git show`` of no object are each reported; existing ones are not."""
    (tmp_path / "docs").mkdir()
    (tmp_path / "results" / "s").mkdir(parents=True)
    (tmp_path / "results" / "s" / "a_on.json").write_text("{}")
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "test_x.py").write_text("def test_a():\n    pass\n")
    (tmp_path / "README.md").write_text(
        "[ok](results/s/a_on.json) [gone](results/s/b.json)\n"
        "`results/s/a_{on,off}.json` `results/s/a_O.json` `results/s/a_on.json`\n"
        "`git show 0000000:results/nothing.json`\n"
        "`tests/test_x.py::test_a` `tests/test_x.py::test_b`\n")
    (tmp_path / "docs" / "x.md").write_text("[up](../results/s/a_on.json) [up2](../results/s/c.json)\n"
                                           "```\nrun --json results/s/a_on.json --out results/s/d.json\n```\n")
    bad = broken_citations(tmp_path)
    assert bad == ["README.md:1: results/s/b.json", "README.md:2: results/s/a_{on,off}.json",
                   "README.md:3: git show 0000000:results/nothing.json", "README.md:4: tests/test_x.py::test_b",
                   "docs/x.md:1: ../results/s/c.json",
                   "docs/x.md:3: results/s/d.json"]


def result_files(root: Path = ROOT) -> list[Path]:
    return sorted(p for p in (root / "results").rglob("*")
                  if p.is_file() and p.name not in (PROVENANCE_FILE, "README.md") and not p.name.startswith("."))


def test_every_result_has_its_provenance():
    files = result_files()
    assert files, "results/ holds no result"
    bad = []
    for f in files:
        rec = read_records(f.parent).get(f.name)
        if rec is None:
            bad.append(f"{f.relative_to(ROOT)}: no record in {PROVENANCE_FILE}")
            continue
        missing = [k for k in FIELDS if k not in rec]
        if missing:
            bad.append(f"{f.relative_to(ROOT)}: fields missing {missing}")
        if rec.get("reconstructed") is not True and UNKNOWN in (rec.get("commit"), rec.get("date")):
            bad.append(f"{f.relative_to(ROOT)}: a run's own record without commit or date")
    assert not bad, "\n".join(bad)


def test_no_record_without_its_file():
    stale = []
    for prov in (ROOT / "results").rglob(PROVENANCE_FILE):
        stale += [f"{prov.parent.relative_to(ROOT)}/{name}" for name in read_records(prov.parent)
                  if not (prov.parent / name).is_file()]
    assert not stale, stale


def test_benchmarks_hold_code_only():
    tracked = subprocess.run(["git", "ls-files", "benchmarks"], cwd=ROOT, capture_output=True, text=True,
                             check=False).stdout.split()
    if not tracked:
        pytest.skip("not a git checkout")
    assert [p for p in tracked if not p.endswith(".py")] == []


def test_a_command_records_what_it_wrote(tmp_path):
    """``track`` records, for each file written under its roots after the start, every field; files
    already there and the provenance file itself get no record; ``--set plant=`` names the plant."""
    import argparse
    import os
    import time

    from biped_controller.studies import provenance
    old = tmp_path / "old.json"
    old.write_text("{}")
    os.utime(old, (time.time() - 60, time.time() - 60))
    args = argparse.Namespace(overrides=["plant=mujoco"], profile=None)
    run = provenance.track(tmp_path, None, args=args, argv=["table", "--json", str(tmp_path / "new.json")])
    (tmp_path / "new.json").write_text("{}")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "fig.png").write_bytes(b"png")
    done = run.finish()
    assert sorted(p.name for p in done) == ["fig.png", "new.json"]
    top, sub = read_records(tmp_path), read_records(tmp_path / "sub")
    assert set(top) == {"new.json"} and set(sub) == {"fig.png"}
    rec = top["new.json"]
    assert set(FIELDS) <= set(rec) and rec["reconstructed"] is False
    assert rec["plant"] == "mujoco" and rec["profile"] is None
    assert rec["command"].endswith(f"table --json {tmp_path / 'new.json'}")
    assert rec["duration_s"] >= 0 and len(rec["load_average"]) == 3 and rec["date"].endswith("+00:00")
    assert rec["clean"] in (True, False) and (rec["clean"] or rec["modified"])
    assert provenance.missing_fields({"commit": "x"}) == [f for f in FIELDS if f != "commit"]
