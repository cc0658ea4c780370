"""The committed fingerprints (results/fingerprints/fingerprints.json) and their reader.

The fingerprints themselves are recomputed by their commands (a refactoring's check, minutes of
simulation: not part of the suite); here: the parser refuses what is not a fingerprint line, the
committed record is complete and was made with the package versions installed now (the exact pins of
requirements.txt: a changed pin needs a new record), and every fingerprint quoted in the docs is the
committed one.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from biped_controller.studies import fingerprint_record as fr

ROOT = Path(__file__).resolve().parents[1]
RECORD = ROOT / fr.DEFAULT_OUT
HEX = "0123456789abcdef" * 4


def test_parse_takes_the_last_line_with_its_label():
    assert fr.parse_fingerprint(f"walk-both ... 0d2f\nfingerprint {HEX}\n\n", "fingerprint") == HEX
    assert fr.parse_fingerprint(f"x\nmujoco fingerprint {HEX}", "mujoco fingerprint") == HEX


@pytest.mark.parametrize("out", ["", "fingerprint abc", f"fingerprint {HEX}\nrun failed", f"mujoco fingerprint {HEX}",
                                 f"fingerprint {HEX.upper()}"])
def test_parse_refuses_what_is_not_a_fingerprint_line(out):
    with pytest.raises(fr.FingerprintError):
        fr.parse_fingerprint(out, "fingerprint")


def test_committed_record_is_complete_and_matches_the_installed_versions():
    rec = json.loads(RECORD.read_text())
    for key in ("rigid", "mujoco"):
        assert re.fullmatch(r"[0-9a-f]{64}", rec[key]), (key, rec[key])
    assert set(rec["packages"]) == set(fr.PACKAGES)
    assert rec["packages"] == fr.package_versions(), "the pins changed: run python -m biped_controller.studies.fingerprint_record"
    prov = json.loads((RECORD.parent / "provenance.json").read_text())
    assert RECORD.name in prov and re.fullmatch(r"[0-9a-f]{40}", prov[RECORD.name]["commit"])


def test_every_fingerprint_quoted_in_the_docs_is_the_committed_one():
    rec = json.loads(RECORD.read_text())
    known = {rec["rigid"], rec["mujoco"]}
    quoted = []
    for doc in [ROOT / "README.md", ROOT / "DESIGN.md", *sorted((ROOT / "docs").glob("*.md"))]:
        lines = doc.read_text().splitlines()
        for i, line in enumerate(lines):
            if "fingerprint" in line or (i and "fingerprint" in lines[i - 1]):
                quoted += [(doc.name, h) for h in re.findall(r"\b[0-9a-f]{64}\b", line)]
    assert quoted, "no doc quotes a fingerprint (docs/mujoco_plant.md did)"
    assert [q for q in quoted if q[1] not in known] == []
