"""Both fingerprints, recorded with the package versions that give them.

    python -m biped_controller.studies.fingerprint_record [--out results/fingerprints/fingerprints.json]

A fingerprint is a sha256 over every bit of every record of a fixed set of closed-loop runs; it is
the check that a restructuring changed no behaviour. It is exact only for one build of the numerical
stack (a different NumPy, Pinocchio, MuJoCo, numba or CPU may change the last bits of a float), so the
committed value is only meaningful beside the versions that produced it. This command runs the two
product checks, each by its own stable command (as a user would, in a subprocess):

- ``python -m biped_controller.studies.fingerprint`` (rigid plant, compiled and Python loops compared)
  whose last line is ``fingerprint <64 hex>``;
- ``python -m biped_controller.studies.plant_compare fingerprint`` (MuJoCo plant) whose last line is
  ``mujoco fingerprint <64 hex>``;

and writes one JSON file: ``{"rigid": hex, "mujoco": hex, "commands": {...}, "packages": {name:
version}, "python": version, "machine": platform}`` with its provenance record beside it.
"""
from __future__ import annotations

import argparse
import importlib.metadata as md
import json
import platform
import re
import subprocess
import sys
from pathlib import Path

from biped_controller.studies import provenance

COMMANDS = {
    "rigid": ([sys.executable, "-m", "biped_controller.studies.fingerprint"], "fingerprint"),
    "mujoco": ([sys.executable, "-m", "biped_controller.studies.plant_compare", "fingerprint"], "mujoco fingerprint"),
}
#: the distributions whose build decides the last bits of the simulated floats
PACKAGES = ("numpy", "scipy", "pin", "mujoco", "numba", "llvmlite", "piqp", "qpsolvers")
DEFAULT_OUT = Path("results") / "fingerprints" / "fingerprints.json"


class FingerprintError(RuntimeError):
    """A fingerprint command failed or did not end with its ``<label> <64 hex>`` line."""


def parse_fingerprint(output: str, label: str) -> str:
    """The 64-hex digest of the last non-empty line of ``output``, which must read ``<label> <hex>``."""
    lines = [s.strip() for s in output.splitlines() if s.strip()]
    if not lines:
        raise FingerprintError(f"no output (expected a last line '{label} <64 hex>')")
    m = re.fullmatch(re.escape(label) + r" ([0-9a-f]{64})", lines[-1])
    if m is None:
        raise FingerprintError(f"last line {lines[-1]!r} is not '{label} <64 hex>'")
    return m.group(1)


def package_versions() -> dict[str, str]:
    """``{distribution: version}`` for :data:`PACKAGES` (``"absent"`` for one not installed)."""
    out = {}
    for name in PACKAGES:
        try:
            out[name] = md.version(name)
        except md.PackageNotFoundError:
            out[name] = "absent"
    return out


def run_all() -> dict:
    """Run both commands; the record (digests, commands, versions, machine)."""
    rec: dict = {"commands": {}}
    for key, (cmd, label) in COMMANDS.items():
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise FingerprintError(f"{' '.join(cmd[1:])} exited with {proc.returncode}: {proc.stderr.strip()[-400:]}")
        rec[key] = parse_fingerprint(proc.stdout, label)
        rec["commands"][key] = "python " + " ".join(cmd[1:])
    rec["packages"] = package_versions()
    rec["python"] = platform.python_version()
    rec["machine"] = f"{platform.system()} {platform.machine()}"
    return rec


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"the JSON file to write (default {DEFAULT_OUT})")
    a = ap.parse_args(argv)
    run = provenance.Run(argv, plant=None)
    try:
        rec = run_all()
    except FingerprintError as exc:
        print(f"fingerprint_record: {exc}", file=sys.stderr)
        return 1
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(rec, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    run.record(a.out)
    print(f"rigid  {rec['rigid']}\nmujoco {rec['mujoco']}\nwritten {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
