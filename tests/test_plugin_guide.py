"""A controller written only from docs/controllers.md, in a new package, gets its table and its map with the
guide's two commands.

The package (written to a temporary directory, imported through PYTHONPATH, registered by its
``module:Class`` string as the guide allows) implements classical computed torque on the fixed reference
q_d(p_d, t - t_touchdown): w = q_d'' + K_v (q_d' - q') + K_p (q_d - q), Gamma = A(q) w + H(q, q'), with the
setup's gains, reference and model the guide names (the plug-in package alone). That is mode ``none``'s law, so the
oracle is the studies' figure of mode none at the paper's cell: 43.75 N (the search's last two bisection
points from a coarse failure at 50 N: 43.75 N survives, 46.875 N falls).

- ``scripts/experiment max-push --controller PKG:Class`` (scan to 100 N: the coarse step 50 N fails, as in
  the full scan) gives 43.75 N;
- ``scripts/capability_map --controller PKG:Class`` at the 25 ms duration, onsets 0 and 0.5 of the first
  step (0.5: the paper's cell), forward, gives 43.75 N in the paper's cell, as ``experiment`` does;
- a package whose controller returns a NaN torque is refused by neither command: its trials are recorded as
  controller faults (max push 0 N, cause ``controller fault``) and the search completes.
"""
from __future__ import annotations

import json
import os
import subprocess
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PY = ROOT / ".venv" / "bin" / "python"

PACKAGE = '''
"""Classical computed torque, written from docs/controllers.md."""
import numpy as np

from biped_controller.plugin.interface import ControlResult


class ComputedTorque:
    description = "classical computed torque on q_d(p_d, t - t_touchdown)"

    def __init__(self, setup):
        self.Kp, self.Kv = setup.gains.Kp, setup.gains.Kv
        self.ref = setup.reference
        self.model = setup.model
        self.t0 = 0.0

    def reset(self, t, stance):
        self.t0 = t

    def on_touchdown(self, t, stance):
        self.t0 = t

    def compute(self, obs):
        tau = obs.t - self.t0
        g = self.ref.at(self.ref.p_d, tau)
        w = g.d2q_dtau2 + self.Kv * (g.dq_dtau - obs.qd) + self.Kp * (g.q - obs.q)
        dyn = self.model.dynamics(obs.q, obs.qd)
        return ControlResult(dyn.A @ w + dyn.H, {"p": self.ref.p_d, "tau": tau, "tau_dot": 1.0})


class Broken(ComputedTorque):
    description = "returns NaN once the push starts"

    def compute(self, obs):
        out = super().compute(obs)
        return ControlResult(out.torque * (np.nan if obs.t > 0.2 else 1.0), out.status)
'''


@pytest.fixture(scope="module")
def package(tmp_path_factory) -> tuple[Path, dict]:
    d = tmp_path_factory.mktemp("userpkg")
    (d / "my_biped_ct").mkdir()
    (d / "my_biped_ct" / "__init__.py").write_text("")
    (d / "my_biped_ct" / "controller.py").write_text(textwrap.dedent(PACKAGE))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(d)] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    return d, env


def _run(cmd: list[str], env: dict) -> subprocess.CompletedProcess:
    p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, (p.stdout[-3000:], p.stderr[-3000:])
    return p


def test_guide_controller_gets_mode_none_max_push_from_the_experiment_command(package, tmp_path):
    _, env = package
    out = tmp_path / "table.json"
    _run(["bash", "scripts/experiment", "max-push", "--controller", "my_biped_ct.controller:ComputedTorque",
          "--max", "100", "--json", str(out)], env)
    r = json.loads(out.read_text())["modes"]["my_biped_ct.controller:ComputedTorque"]
    assert r["max_force"] == 43.75 and r["first_failure"] == 46.875, r
    assert r["failure_cause"].startswith("fell"), r


def test_guide_controller_gets_its_map_cell(package, tmp_path):
    _, env = package
    out = tmp_path / "map.json"
    name = "my_biped_ct.controller:ComputedTorque"
    _run(["bash", "scripts/capability_map", "--controller", name, "--durations", "0.025", "--phases", "2",
          "--directions", "forward", "--max", "100", "--workers", "1", "--no-progress",
          "--store", str(tmp_path / "records.jsonl"), "--json", str(out)], env)
    recs = [json.loads(line) for line in (tmp_path / "records.jsonl").read_text().splitlines() if line.strip()]
    at = {r["force"]: r["survived"] for r in recs if r["mode"] == name and r["phase"] == 0.5}
    assert at.get(43.75) is True and at.get(46.875) is False, at
    assert not any(f > 43.75 and ok for f, ok in at.items() if f <= 50.0), at


def test_a_faulting_controller_is_recorded_and_the_search_goes_on(package, tmp_path):
    _, env = package
    out = tmp_path / "broken.json"
    _run(["bash", "scripts/experiment", "max-push", "--controller", "my_biped_ct.controller:Broken",
          "--max", "100", "--json", str(out)], env)
    r = json.loads(out.read_text())["modes"]["my_biped_ct.controller:Broken"]
    assert r["max_force"] == 0.0 and r["first_failure"] is not None
    assert all(t["reason"].startswith("controller fault") and "non-finite torque" in t["reason"] for t in r["trials"])


def test_an_unknown_controller_is_one_line_and_exit_2(package):
    _, env = package
    p = subprocess.run([str(PY), "-m", "biped_controller.studies.experiment", "max-push", "--controller",
                        "my_biped_ct.controller:Nope"], cwd=ROOT, env=env, capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 2
    assert "Nope" in p.stderr and len(p.stderr.strip().splitlines()) <= 3, p.stderr
