"""Every entry point takes ``--robot NAME|PATH`` (issue 40): each script of ``scripts/`` and each ``main`` of
the product's studies, subcommand by subcommand, parse-only (``--help`` in this process, nothing run).

A new script, study or subcommand must either take the flag or be named below with the reason it does not
need one: the lists are checked against ``scripts/`` and ``studies/`` themselves, so one cannot be forgotten.
"""
from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
STUDIES = ROOT / "src" / "biped_controller" / "biped_controller" / "studies"

#: scripts that start no study of a robot, with the reason
SCRIPTS_WITHOUT_ROBOT = {
    "_prelude.sh": "sourced by the other scripts",
    "env.sh": "sourced by the other scripts",
    "setup": "installs the environment",
    "setup-train": "installs the optional training extra",
    "train": "trains the baseline its config names (config/training/NAME.yaml) on the default robot only: the "
             "trainer takes no robot yet (its policy.json records robot biped7)",
    "test": "runs the test suite",
    "bag": "reads a recording, which carries its own robot (/robot_description)",
    "run_node": "one node as ros2 run starts it: the robot is the node's parameter robot (-p robot:=NAME|PATH)",
    "robot": "the robot is its positional NAME|PATH (scripts/robot build|check NAME|PATH)",
    "bench": "benchmarks.run, which tests/ may not import (tests/test_layout.py): its source is read instead",
}
#: (module, subcommand) that need no robot, with the reason
SUBCOMMANDS_WITHOUT_ROBOT = {
    ("biped_controller.studies.controllers", "list"): "lists the registered controllers",
    ("biped_controller.studies.controllers", "slices"): "compares map files, which name their robot",
    ("biped_controller.studies.plant_compare", "fingerprint"): "the default robot's fingerprint, by definition",
    ("biped_controller.studies.robots", None): "the robot is each subcommand's positional NAME|PATH",
}
#: studies whose main is about the default robot only, with the reason
STUDIES_WITHOUT_ROBOT = {
    "fingerprint": "the default robot's fingerprint, by definition (BRIEF: both fingerprints unchanged)",
    "fingerprint_record": "records the default robot's fingerprints",
    "headline": "the README's headline table: the default robot's",
}


def _script_modules(script: Path) -> list[str]:
    return re.findall(r"-m ([A-Za-z_][\w.]*)", script.read_text(encoding="utf-8"))


def _help(module: str, argv: list[str], capsys) -> str:
    main = importlib.import_module(module).main
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--help"])
    assert exc.value.code == 0, (module, argv)
    return capsys.readouterr().out


def _subcommands(text: str) -> list[str]:
    """The subcommands of a usage line (``{a,b} ...``; an option's choices ``[--x {a,b}]`` are not)."""
    m = re.search(r"(?:\]|\n)\s*\{([\w,-]+)\}\s+\.\.\.", text.split("\n\n")[0])
    return m.group(1).split(",") if m else []


def _entry_points() -> list[tuple[str, str]]:
    """(script or study, module) of every script of scripts/ and every main of studies/."""
    out = []
    for script in sorted((ROOT / "scripts").iterdir()):
        if script.name in SCRIPTS_WITHOUT_ROBOT:
            continue
        mods = _script_modules(script)
        assert mods, f"scripts/{script.name}: starts no python -m module; take --robot or name it in SCRIPTS_WITHOUT_ROBOT"
        out += [(f"scripts/{script.name}", m) for m in mods]
    for path in sorted(STUDIES.rglob("*.py")):
        if "def main(" not in path.read_text(encoding="utf-8") or path.stem in STUDIES_WITHOUT_ROBOT:
            continue
        mod = "biped_controller." + ".".join(path.relative_to(STUDIES.parent).with_suffix("").parts)
        out.append((f"studies/{path.relative_to(STUDIES)}", mod))
    return out


def test_the_lists_of_exemptions_name_what_exists():
    """An exemption names a script or a study that exists (a stale one would hide nothing)."""
    scripts = {p.name for p in (ROOT / "scripts").iterdir()}
    assert set(SCRIPTS_WITHOUT_ROBOT) <= scripts
    assert all((STUDIES / f"{s}.py").is_file() for s in STUDIES_WITHOUT_ROBOT)
    assert len(_entry_points()) >= 15
    assert '"--robot"' in (ROOT / "benchmarks" / "run.py").read_text(encoding="utf-8")    # scripts/bench


def test_every_entry_point_takes_robot(capsys):
    """scripts/ and studies/: each module (and each of its subcommands) lists --robot NAME|PATH in its help."""
    missing = []
    for where, module in dict.fromkeys(_entry_points()):
        if (module, None) in SUBCOMMANDS_WITHOUT_ROBOT:
            continue
        text = _help(module, [], capsys)
        subs = _subcommands(text)
        if not subs:
            if "--robot" not in text:
                missing.append(f"{where} ({module})")
            continue
        for sub in subs:
            if (module, sub) in SUBCOMMANDS_WITHOUT_ROBOT:
                continue
            if "--robot" not in _help(module, [sub], capsys):
                missing.append(f"{where} ({module} {sub})")
    assert not missing, "no --robot: " + "; ".join(missing)


def test_a_module_without_the_flag_is_found(capsys):
    """Negative controls: the check finds a parser without --robot (the fingerprint study's) and a subcommand
    without it (controllers list); an option's choices are not taken for subcommands."""
    assert "--robot" not in _help("biped_controller.studies.fingerprint", [], capsys)
    text = _help("biped_controller.studies.controllers", [], capsys)
    assert "list" in _subcommands(text)
    assert "--robot" not in _help("biped_controller.studies.controllers", ["list"], capsys)
    assert _subcommands("usage: x [-h] [--observer {on,off} [{on,off} ...]] [--what {a,b}]") == []
    assert _subcommands("usage: x [-h]\n       {walk,push} ...") == ["walk", "push"]


def test_soak_scales_its_forces_and_judges_with_the_bags_robot():
    """scripts/soak --robot: its force defaults scale with M sqrt(g L) (exactly 1 for the default robot, named
    or not; the ratio of the descriptions' values for another), and the bag check's model can be built from a
    recorded /robot_description: another robot's URDF gives that robot's mass, not the default robot's (the
    check computed a 70 kg robot's impulses with the 41 kg model before)."""
    import math

    from biped_model.description import load_description, make_urdf
    from biped_model.floating import FloatingModel
    from biped_model.robot import RobotError, resolve_robot
    from biped_sim.graph.soak import robot_force_scale
    assert robot_force_scale(None) == robot_force_scale("biped7") == 1.0
    d, b = resolve_robot("human70").description(), load_description()
    k = robot_force_scale("human70")
    assert math.isclose(k, d.total_mass * math.sqrt(d.leg_length) / (b.total_mass * math.sqrt(b.leg_length)), rel_tol=1e-12)
    assert k > 1.5
    with pytest.raises(RobotError):
        robot_force_scale("no_such_robot")
    fm = FloatingModel(urdf=make_urdf(d))
    assert math.isclose(fm.mass, d.total_mass, rel_tol=1e-9) and not math.isclose(fm.mass, b.total_mass, rel_tol=1e-3)
    assert FloatingModel().urdf == make_urdf(b)
