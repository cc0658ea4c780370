"""Provenance of a study's summary: the repository's commit and modified files."""
from __future__ import annotations


def git_state() -> dict:
    """The commit and the modified/untracked files of the repository (provenance of a summary); empty
    when git is not available."""
    import subprocess
    from biped_sim.robot.settings import repo_root
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=repo_root(), capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "src", "config"], cwd=repo_root(),
                               capture_output=True, text=True, check=True).stdout.splitlines()
    except (OSError, subprocess.CalledProcessError):
        return {}
    return {"commit": head, "modified": [x.strip() for x in dirty]}
