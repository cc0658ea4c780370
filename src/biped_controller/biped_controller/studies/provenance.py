"""Provenance of results: which code, which command, when, on how loaded a machine, how long.

One record per result file, kept in a ``provenance.json`` beside it (one per directory, keyed by file
name; the layout is documented in ``results/README.md``). A record holds every field of :data:`FIELDS`:

- ``commit``        the repository's HEAD (40 hex digits) when the file was written
- ``clean``         True when ``git status --porcelain`` lists nothing under :data:`CODE_PATHS` (the
                    code and configuration a result depends on), False otherwise (``modified`` then
                    lists the entries)
- ``command``       the command line, ``python -m <module> <args>`` (arguments shell-quoted)
- ``date``          UTC, ISO 8601 to the second, when the record was written (the end of the run)
- ``load_average``  ``os.getloadavg()`` at that moment: 1, 5 and 15 min averages of runnable tasks
- ``duration_s``    wall-clock seconds from the start of the tracking to the record (time.monotonic)
- ``plant``         ``"rigid"`` / ``"mujoco"`` where the result depends on it, None where it does not
- ``profile``       the named settings profile of the run, None when the run names none
- ``reconstructed`` False for a record written by the run itself; True for a record rebuilt later from
                    git and from the file's own contents, whose unrecoverable fields hold :data:`UNKNOWN`

and, in every record written since robots became directories (:data:`ROBOT_FIELDS`; a record written before
has neither and still loads):

- ``robot``         the robot of the run: its directory's name under ``robots/`` (``biped7`` by default),
                    else the directory's path
- ``robot_hash``    sha256 of that robot's description (``biped_model.robot.description_hash``: its physical
                    values), :data:`UNKNOWN` when the description cannot be read

A field that could not be known holds the string :data:`UNKNOWN`, never a guess.
"""
from __future__ import annotations

import atexit
import datetime as _dt
import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

PROVENANCE_FILE = "provenance.json"
UNKNOWN = "unknown"
FIELDS = ("commit", "clean", "command", "date", "load_average", "duration_s", "plant", "profile", "reconstructed")
#: fields every new record holds, absent from the records written before them
ROBOT_FIELDS = ("robot", "robot_hash")
CODE_PATHS = ("src", "config", "robots", "benchmarks", "lab", "scripts", "requirements.txt")


def _repo_root() -> Path:
    from biped_model.settings import repo_root
    return Path(repo_root())


def git_state() -> dict:
    """The commit and the modified/untracked files of the repository (provenance of a summary); empty
    when git is not available."""
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=_repo_root(), capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "src", "config"], cwd=_repo_root(),
                               capture_output=True, text=True, check=True).stdout.splitlines()
    except (OSError, subprocess.CalledProcessError):
        return {}
    return {"commit": head, "modified": [x.strip() for x in dirty]}


def tree_state() -> dict:
    """``commit``, ``clean`` and ``modified`` (porcelain entries under :data:`CODE_PATHS`); the first two
    are :data:`UNKNOWN` when git is not available."""
    root = _repo_root()
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", *CODE_PATHS], cwd=root,
                               capture_output=True, text=True, check=True).stdout.splitlines()
    except (OSError, subprocess.CalledProcessError):
        return {"commit": UNKNOWN, "clean": UNKNOWN, "modified": []}
    modified = [x.strip() for x in dirty if x.strip()]
    return {"commit": head, "clean": not modified, "modified": modified}


def command_line(argv: list[str] | None = None) -> str:
    """``python -m <module> <args>`` of this process (or ``python <script> <args>``), shell-quoted;
    ``argv`` replaces ``sys.argv[1:]`` when a ``main(argv)`` was called with explicit arguments."""
    args = list(sys.argv[1:] if argv is None else argv)
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    head = ["python", "-m", spec.name] if spec is not None and spec.name else ["python", sys.argv[0] or "-"]
    return shlex.join(head + [str(a) for a in args])


def _utc_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()


def provenance_path(path: os.PathLike | str) -> Path:
    """The provenance file that holds the record of ``path``."""
    return Path(path).parent / PROVENANCE_FILE


def read_records(directory: os.PathLike | str) -> dict:
    """The records of a directory's ``provenance.json`` (file name -> record); empty when there is none."""
    p = Path(directory) / PROVENANCE_FILE
    if not p.exists():
        return {}
    return json.loads(p.read_text(encoding="utf-8"))


def write_records(directory: os.PathLike | str, records: dict) -> Path:
    """Merge ``records`` (file name -> record) into the directory's ``provenance.json`` (sorted keys,
    written through a temporary file and a rename, so a reader never sees half a file)."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    merged = read_records(d)
    merged.update(records)
    p = d / PROVENANCE_FILE
    tmp = p.with_name(f".{PROVENANCE_FILE}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(merged, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    os.replace(tmp, p)
    return p


def missing_fields(record: dict) -> list[str]:
    """The fields of :data:`FIELDS` absent from ``record`` (a present field may hold :data:`UNKNOWN`)."""
    return [f for f in FIELDS if f not in record]


class Run:
    """One command's provenance: started at construction, recorded for each file it wrote.

    ``record(*paths)`` writes one record per path into the provenance file beside it.
    ``track(*roots)`` instead records, at interpreter exit, every file under ``roots`` (files, or
    directories searched recursively) modified since the start; None roots are ignored.
    """

    def __init__(self, argv: list[str] | None = None, *, plant: str | None = None, profile: str | None = None,
                 command: str | None = None, robot: str | None = None) -> None:
        self.t0 = time.monotonic()
        self.wall0 = time.time()
        self.command = command if command is not None else command_line(argv)
        self.plant = plant
        self.profile = profile
        self.robot, self.robot_hash = robot_identity(robot)
        self._roots: list[Path] = []
        self._registered = False

    def fields(self) -> dict:
        """The record of a file written now (every field of :data:`FIELDS`, plus ``modified``)."""
        state = tree_state()
        rec = {"commit": state["commit"], "clean": state["clean"], "command": self.command, "date": _utc_now(),
               "load_average": [round(x, 2) for x in os.getloadavg()],
               "duration_s": round(time.monotonic() - self.t0, 3), "plant": self.plant, "profile": self.profile,
               "reconstructed": False, "robot": self.robot, "robot_hash": self.robot_hash}
        if state["modified"]:
            rec["modified"] = state["modified"]
        return rec

    def record(self, *paths: os.PathLike | str | None) -> dict:
        """Write the record of each existing path (None skipped); returns path -> record."""
        done: dict[Path, dict] = {}
        by_dir: dict[Path, dict] = {}
        rec = None
        for p in paths:
            if p is None:
                continue
            p = Path(p)
            if not p.is_file() or p.name == PROVENANCE_FILE:
                continue
            rec = rec or self.fields()
            by_dir.setdefault(p.resolve().parent, {})[p.name] = rec
            done[p] = rec
        for d, recs in by_dir.items():
            write_records(d, recs)
        return done

    def written(self) -> list[Path]:
        """Files under the tracked roots modified since the start of the run."""
        out: list[Path] = []
        for r in self._roots:
            cands = [r] if r.is_file() else (sorted(q for q in r.rglob("*") if q.is_file()) if r.is_dir() else [])
            for q in cands:
                if q.name == PROVENANCE_FILE or q.name.startswith(f".{PROVENANCE_FILE}"):
                    continue
                if q.stat().st_mtime >= self.wall0 and q not in out:
                    out.append(q)
        return out

    def track(self, *roots: os.PathLike | str | None) -> "Run":
        """Record, at exit, every file under ``roots`` that this run modified."""
        self._roots.extend(Path(r) for r in roots if r is not None)
        if not self._registered:
            atexit.register(self.finish)
            self._registered = True
        return self

    def finish(self) -> dict:
        """Record the tracked files now (idempotent: a file is recorded once per call)."""
        return self.record(*self.written())


def track(*roots: os.PathLike | str | None, args=None, argv: list[str] | None = None,
          plant: str | None = None, profile: str | None = None, robot: str | None = None) -> Run:
    """Start a :class:`Run` and record, at exit, the files it writes under ``roots``. ``args`` (an argparse
    namespace) supplies ``plant``, ``profile`` and ``robot`` (``--robot``) when it has them (``--set plant=...``
    included)."""
    if args is not None:
        profile = profile if profile is not None else getattr(args, "profile", None)
        plant = plant if plant is not None else _plant_of(args)
        robot = robot if robot is not None else getattr(args, "robot", None)
    return Run(argv, plant=plant, profile=profile, robot=robot).track(*roots)


def robot_identity(robot: str | None) -> tuple[str, str]:
    """(``robot``, ``robot_hash``) of a record: the robot ``robot`` names (None or "": the default robot) and
    its description's sha256; the hash is :data:`UNKNOWN` when the description cannot be read."""
    from biped_model.robot import RobotError, resolve_robot, robot_label
    from biped_model.settings import DEFAULT_ROBOT
    try:
        label = robot_label(robot)
        return label, resolve_robot(robot).description_hash()
    except RobotError:
        return (str(robot) if robot else DEFAULT_ROBOT), UNKNOWN


def _plant_of(args) -> str | None:
    """The plant an argparse namespace names: ``--plant``, a ``--set plant=NAME``, or, for a command that
    takes ``--set`` but names neither, the plant of its profile (:func:`profile_plant`) or, without a profile,
    the configured default (``config/simulator.yaml``); None for a command without settings."""
    p = getattr(args, "plant", None)
    if isinstance(p, str):
        return p
    overrides = getattr(args, "overrides", None)
    if overrides is None:
        overrides = getattr(args, "set", None)
    if overrides is None:
        return None
    for s in overrides:
        for item in (s if isinstance(s, (list, tuple)) else [s]):
            if isinstance(item, str) and item.replace(" ", "").startswith("plant="):
                return item.split("=", 1)[1].strip()
    profile = getattr(args, "profile", None)
    if profile:
        return profile_plant(profile)
    return default_plant()


def profile_plant(name: str) -> str:
    """The plant a run under profile ``name`` uses: the profile's ``plant`` setting, else the configured default
    (``config/simulator.yaml``); :data:`UNKNOWN` when the profile cannot be read."""
    from biped_model.profiles import ProfileError, load_profile
    try:
        settings = dict(load_profile(name).settings)
    except (ProfileError, OSError):
        return UNKNOWN
    return str(settings["plant"]) if "plant" in settings else default_plant()


def default_plant() -> str:
    """The ``plant`` value of ``config/simulator.yaml`` (:data:`UNKNOWN` when it cannot be read)."""
    try:
        import yaml
        doc = yaml.safe_load((_repo_root() / "config" / "simulator.yaml").read_text(encoding="utf-8"))
        return str(doc["plant"]["value"])
    except (OSError, KeyError, TypeError, ImportError):
        return UNKNOWN
