"""The example plug-in packages under ``examples/`` keep their own tests (a user copies the package with
them); the suite runs each package's tests as that package's user would, in a pytest of its own, so that
CI checks them too."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = sorted(p.parent for p in (ROOT / "examples").glob("*/pyproject.toml"))


def test_there_is_an_example_package():
    assert PACKAGES, "no package with a pyproject.toml under examples/"


@pytest.mark.parametrize("package", PACKAGES, ids=lambda p: p.name)
def test_example_package_tests_pass(package):
    """``pytest <package>/tests`` from the package's directory exits 0 with at least one test run."""
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests"], cwd=package,
                         capture_output=True, text=True, timeout=1200)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    assert " passed" in run.stdout, run.stdout[-2000:]
