"""Lint: ``ruff check src tests benchmarks lab examples`` with the repository's ``ruff.toml`` (pyflakes-class F rules)
finds nothing. A negative control first: the same ruff and configuration flag a planted undefined name and
an unused import, so a ruff that checks nothing cannot pass silently."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUFF = Path(sys.executable).with_name("ruff")      # the venv's pinned ruff (requirements.txt)
CONFIG = ROOT / "ruff.toml"


def ruff_check(*paths: str | Path, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([str(RUFF), "check", "--no-cache", "--config", str(CONFIG), *map(str, paths)],
                          cwd=cwd, capture_output=True, text=True, timeout=300)


def test_ruff_flags_planted_errors(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("import os\n\n\ndef f(x: Simulator) -> int:\n    return 1\n")
    r = ruff_check(bad, cwd=tmp_path)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "F821" in r.stdout and "Simulator" in r.stdout, r.stdout
    assert "F401" in r.stdout, r.stdout


def test_ruff_finds_nothing_in_src_tests_benchmarks_lab_examples():
    r = ruff_check("src", "tests", "benchmarks", "lab", "examples")
    assert r.returncode == 0, f"ruff findings:\n{r.stdout}{r.stderr}"
