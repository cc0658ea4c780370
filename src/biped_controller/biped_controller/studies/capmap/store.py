"""The map's records: one JSON object per simulation in a JSON Lines file, resumable, keyed by the
settings' fingerprint."""
from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict
from pathlib import Path
from typing import Iterable


from biped_controller.studies.trial import record, stop, survival
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.settings import check_settings
from biped_controller.studies.capmap.spec import MapError, MapSpec

RECORD_VERSION = 1


class StoreError(MapError):
    """The record store cannot be read (a malformed line other than a torn last one; the line is named)."""



def fingerprint(spec: MapSpec) -> str:
    """sha256 (16 hex digits) of everything a record depends on besides its own key and the code: the
    effective controller and simulator settings, the robot description, the gait family file, the
    survival rule (its floors, band factor and window), the early stop's settings (``config/studies.yaml``) and the push height. The code is not in it (the tree is edited by many hands, and
    a comment must not void a map): after a change of the controller or the simulator that changes
    results, use a new store; every summary records the git commit and the modified files."""
    ctx = context()
    h = hashlib.sha256()
    inputs = {
        "version": RECORD_VERSION,
        "settings": check_settings(spec.settings),
        "description": {k: v for k, v in asdict(ctx.desc).items() if k != "source"},
        # the rule's verdicts depend on its band's factor and window (config/studies.yaml) besides the settings
        # hashed above (the band's unpushed walk is a function of those): a store is not resumed across them
        "survival": survival.survival_rule().identity(),
        # the early stop decides outcomes too (a trial it ends is counted survived): a store made under other
        # tolerances (e.g. before early_stop_lambda existed, when mode lambda's cells were wrong) is not resumed
        # (the plant's own: the rigid plant's dict is the one every rigid store was made with)
        "early_stop": stop.identity(spec.settings),
        "height": spec.height,
    }
    h.update(json.dumps(inputs, sort_keys=True, default=str).encode())
    h.update(ctx.robot.family_path.read_bytes())
    return h.hexdigest()[:16]


# ------------------------------------------------------------------------------------------ store
class RecordStore:
    """JSON Lines file of simulation records, appended one line per record (flushed at once)."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.repaired_bytes = 0

    def load(self) -> list[dict]:
        """Every record in the file (none if it does not exist), each with the trial record's ``seed`` and
        ``fault_kind`` (``trial.record.complete``: filled in records written before they existed; the file
        is not rewritten). A last line without its newline that does not parse (a write cut short) is
        removed from the file; any other malformed line, or a ``seed`` or ``fault_kind`` of the wrong type,
        raises :class:`StoreError` naming the line."""
        if not self.path.exists():
            return []
        data = self.path.read_bytes()
        out = []
        pos = 0
        lineno = 0
        while pos < len(data):
            nl = data.find(b"\n", pos)
            end = len(data) if nl < 0 else nl
            line = data[pos:end]
            lineno += 1
            if line.strip():
                try:
                    rec = json.loads(line)
                    if not isinstance(rec, dict):
                        raise ValueError("not a JSON object")
                except ValueError as exc:
                    if nl < 0:   # torn last line: cut it off so that appends start on a fresh line
                        with open(self.path, "r+b") as fh:
                            fh.truncate(pos)
                        self.repaired_bytes = len(data) - pos
                        break
                    raise StoreError(f"{self.path}:{lineno}: not a JSON record ({exc})") from exc
                if nl < 0:       # a complete record without its newline: add it before appending
                    with open(self.path, "ab") as fh:
                        fh.write(b"\n")
                try:
                    out.append(record.complete(rec))
                except record.TrialRecordError as exc:
                    raise StoreError(f"{self.path}:{lineno}: {exc}") from exc
            pos = end + 1
        return out

    def append(self, records: Iterable[dict]) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, "a", encoding="utf-8") as fh:
            for r in records:
                fh.write(json.dumps(r, sort_keys=True, allow_nan=False) + "\n")
            fh.flush()


def load_records(path: str | os.PathLike, fingerprint_: str | None = None) -> list[dict]:
    """The records of a store (for notebooks), optionally only those of one fingerprint."""
    recs = RecordStore(path).load()
    return [r for r in recs if fingerprint_ is None or r.get("fingerprint") == fingerprint_]
