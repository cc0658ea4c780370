"""What a run's controller was, for its record (the ROS graph's latched ``/controller/info``, the bag's
``biped_controller`` metadata record): its registered name, its options, and the SHA-256 of every file it
reads (an option naming an existing file, and whatever the controller's own ``provenance()`` reports, e.g.
an ONNX policy's file, also when a committed policy binds it by name).

:func:`controller_provenance` gives a plain mapping (strings, numbers, nested mappings) that YAML writes as
is; :func:`file_sha256` the hash of one file (hex).
"""
from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Mapping


def file_sha256(path: str | Path) -> str:
    """SHA-256 (hex) of the bytes of the file ``path``."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def controller_provenance(name: str, options: Mapping[str, object], controller: object = None) -> dict:
    """``{controller: name, options: {...}, files: {option: {path, sha256}}}`` plus the keys of
    ``controller.provenance()`` when the controller (or the one a ``GuardedController`` wraps, its ``inner``)
    has that method. ``files`` lists the options whose value names an existing file (its absolute path)."""
    out: dict = {"controller": str(name), "options": {str(k): v for k, v in options.items()}}
    files = {}
    for k, v in options.items():
        if isinstance(v, str) and v and Path(v).is_file():
            files[str(k)] = {"path": str(Path(v).resolve()), "sha256": file_sha256(v)}
    if files:
        out["files"] = files
    inner = getattr(controller, "inner", controller)
    own = getattr(inner, "provenance", None)
    if callable(own):
        out.update(own())
    return out
