"""The layout rules of DESIGN.md, checked on the source (every import, also those inside functions):

- pure-core modules import no ROS (rclpy, message packages);
- ``biped_sim`` never imports ``biped_controller`` (the simulator does not depend on the controller);
- rooms by concern: each sub-package imports only the rooms below it (``ROOMS``): the robot layer
  nothing but itself, the plant the robot, the controller core and the gait generation the robot
  (never the plant or the ROS plumbing), the studies the plant too, the nodes whatever they serve;
  inside the controller core, the QP below the sensing below the control law (a room named in
  ``ROOMS`` admits its sub-rooms: ``biped_controller.core`` stands for all three);
- no circular imports between the project's modules;
- the product apart from the lab: no module of ``src/`` and no file of ``tests/`` imports ``lab`` (the
  investigations) or ``benchmarks`` (what ``scripts/bench`` runs); a test of either runs it as its user does.

The checker is exercised on a small synthetic package first (negative controls), so a checker that
finds nothing cannot pass silently.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"biped_model": ROOT / "src" / "biped_model" / "biped_model",
            "biped_sim": ROOT / "src" / "biped_sim" / "biped_sim",
            "biped_controller": ROOT / "src" / "biped_controller" / "biped_controller"}
# The ROS layer: nodes and the tools that talk to a running graph. Everything else is pure core.
ROS_LAYER = {
    "biped_sim.graph.simulator_node", "biped_sim.graph.disturbance_node", "biped_sim.graph.recorder_node", "biped_sim.live.bridge_node",
    "biped_sim.graph.names", "biped_sim.graph.params", "biped_sim.graph.launch", "biped_sim.graph.push_client",
    "biped_sim.graph.imu", "biped_sim.graph.sim_clock",
    "biped_sim.graph.demo", "biped_sim.graph.soak", "biped_controller.graph.controller_node",
}
# room -> the rooms it may import (besides itself). A module's room is its sub-package.
ROOMS = {
    "biped_model": set(),
    "biped_sim.plant": {"biped_model"},
    "biped_sim.recording": {"biped_model"},
    "biped_sim.graph": {"biped_model", "biped_sim.plant", "biped_sim.recording"},
    "biped_sim.live": {"biped_model", "biped_sim.graph", "biped_sim.recording"},
    "biped_controller.core.qp": {"biped_model"},
    "biped_controller.core.sensing": {"biped_model", "biped_controller.core.qp"},
    "biped_controller.core.control": {"biped_model", "biped_controller.core.qp", "biped_controller.core.sensing"},
    "biped_controller.gaits": {"biped_model", "biped_controller.core"},
    "biped_controller.plugin": {"biped_model", "biped_sim.plant", "biped_controller.core"},
    "biped_controller.closed_loop": {"biped_model", "biped_sim.plant", "biped_controller.core", "biped_controller.plugin"},
    "biped_controller.studies": {"biped_model", "biped_sim.plant", "biped_controller.core", "biped_controller.gaits",
                                 "biped_controller.plugin", "biped_controller.closed_loop"},
    "biped_controller.graph": {"biped_model", "biped_sim.graph", "biped_controller.core", "biped_controller.plugin"},
    # the Gymnasium environment and the policy controllers: the plug-in loop's plant and interface, the studies'
    # settings (profiles, robots); nothing imports it but by name (entry points, gymnasium ids)
    "biped_controller.policy": {"biped_model", "biped_sim.plant", "biped_controller.plugin", "biped_controller.studies"},
    # the learned baseline's trainer, export and evaluation: the environment and policy files of policy, the studies'
    # CLI pieces and provenance; nothing imports it (scripts/train, python -m)
    "biped_controller.learning": {"biped_model", "biped_controller.policy", "biped_controller.studies"},
}
ROS_ROOTS = {"rclpy", "rcl_interfaces", "rosgraph_msgs", "std_msgs", "sensor_msgs", "geometry_msgs",
             "builtin_interfaces", "tf2_msgs", "biped_msgs_py", "std_srvs", "ament_index_python"}


def module_imports(path: Path, module: str) -> set[str]:
    """Absolute names of every module imported anywhere in the file (relative imports resolved)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    pkg = module.rsplit(".", 1)[0] if not path.name == "__init__.py" else module
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            out.add(target)
            # `from pkg import mod` imports the submodule pkg.mod when it exists
            out.update(f"{target}.{a.name}" for a in node.names)
    return out


def collect(packages: dict[str, Path]) -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for name, d in packages.items():
        for f in sorted(d.rglob("*.py")):
            parts = [name, *f.relative_to(d).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mod = ".".join(parts)
            graph[mod] = module_imports(f, mod)
    known = set(graph)
    return {m: {i for i in imps if i in known and i != m} | {i for i in imps if i not in known}
            for m, imps in graph.items()}


def violations(graph: dict[str, set[str]], ros_layer: set[str]) -> list[str]:
    out = []
    for mod, imps in sorted(graph.items()):
        roots = {i.split(".")[0] for i in imps}
        if mod not in ros_layer and roots & ROS_ROOTS:
            out.append(f"pure-core module {mod} imports ROS: {sorted(roots & ROS_ROOTS)}")
        if mod.startswith("biped_sim") and "biped_controller" in roots:
            out.append(f"{mod} imports biped_controller (the simulator must not depend on the controller)")
        if mod.startswith("biped_model") and roots & {"biped_sim", "biped_controller"}:
            out.append(f"{mod} imports {sorted(roots & {'biped_sim', 'biped_controller'})} (the robot model is below both sides)")
    return out


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Elementary cycles found by depth-first search over the project's own modules (one per back edge)."""
    known = set(graph)
    edges = {m: sorted(i for i in imps if i in known) for m, imps in graph.items()}
    found, state, stack = [], {}, []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for n in edges[m]:
            if state.get(n) == 1:
                found.append(stack[stack.index(n):] + [n])
            elif n not in state:
                visit(n)
        stack.pop()
        state[m] = 2

    for m in sorted(edges):
        if m not in state:
            visit(m)
    return found


@pytest.fixture
def bad_package(tmp_path):
    """biped_sim-like package with a ROS import in the core, a controller import and a cycle."""
    sim = tmp_path / "biped_sim"
    ctl = tmp_path / "biped_controller"
    sim.mkdir()
    ctl.mkdir()
    (sim / "__init__.py").write_text("")
    (sim / "core.py").write_text("def f():\n    import rclpy\n")
    (sim / "a.py").write_text("from . import b\n")
    (sim / "b.py").write_text("def g():\n    from .a import x\n")
    (sim / "uses_ctl.py").write_text("def h():\n    from biped_controller.x import y\n")
    (ctl / "__init__.py").write_text("")
    (ctl / "x.py").write_text("y = 1\n")
    return {"biped_sim": sim, "biped_controller": ctl}


def test_checker_finds_planted_violations(bad_package):
    g = collect(bad_package)
    v = violations(g, ros_layer=set())
    assert any("biped_sim.core imports ROS" in s for s in v), v
    assert any("biped_sim.uses_ctl imports biped_controller" in s for s in v), v
    cyc = cycles(g)
    assert any({"biped_sim.a", "biped_sim.b"} <= set(c) for c in cyc), cyc


def test_project_modules_found():
    g = collect(PACKAGES)
    for m in ("biped_sim.plant.rigid", "biped_model.gait_family", "biped_controller.core.control.controller", "biped_controller.core.qp.solver"):
        assert m in g, sorted(g)
    assert len(g) >= 30


def test_pure_core_imports_no_ros_and_sim_never_imports_controller():
    assert violations(collect(PACKAGES), ROS_LAYER) == []


def test_no_circular_imports():
    assert cycles(collect(PACKAGES)) == []


def test_ros_layer_names_exist():
    """The ROS-layer list names real modules (a typo would silently make a module 'pure')."""
    g = collect(PACKAGES)
    missing = {m for m in ROS_LAYER if m not in g}
    assert not missing, missing


# packages whose own __init__ is no room's module (their modules all live in sub-packages)
PACKAGE_ROOTS = {"biped_sim", "biped_controller", "biped_controller.core"}


def room_of(mod: str, rooms: dict[str, set[str]] = ROOMS) -> str | None:
    """The longest room (a key of ``rooms``) that is a package of ``mod`` or ``mod`` itself; None if none."""
    parts = mod.split(".")
    for k in range(len(parts), 0, -1):
        if ".".join(parts[:k]) in rooms:
            return ".".join(parts[:k])
    return None


def may_import(room: str, other: str, rooms: dict[str, set[str]]) -> bool:
    """A room imports itself, a room it lists, or a sub-room of a room it lists."""
    return other == room or any(other == r or other.startswith(r + ".") for r in rooms[room])


def room_violations(graph: dict[str, set[str]], rooms: dict[str, set[str]]) -> list[str]:
    """Imports from a module's room into a room it may not import (``rooms``); a project module outside
    every room (directly in a package, the package roots' ``__init__`` apart) is a violation too."""
    out = []
    for mod, imps in sorted(graph.items()):
        if mod in PACKAGE_ROOTS:
            continue
        room = room_of(mod, rooms)
        if room is None:
            out.append(f"{mod} is in no room")
            continue
        for i in sorted(imps):
            r = room_of(i, rooms)
            if i.split(".")[0] in ("biped_model", "biped_sim", "biped_controller") and r is not None \
                    and not may_import(room, r, rooms):
                out.append(f"{mod} ({room}) imports {i} ({r})")
    return out


def test_room_checker_finds_planted_violations():
    g = {"biped_model.a": {"biped_sim.plant.b"}, "biped_sim.plant.b": {"biped_model.a"},
         "biped_controller.core.qp.c": {"biped_sim.plant.b", "biped_sim.graph.names", "biped_controller.core.control.d"},
         "biped_controller.core.control.d": {"biped_controller.core.qp.c", "biped_controller.core.sensing.e"},
         "biped_controller.core.sensing.e": {"biped_controller.core.control.d"},
         "biped_controller.gaits.f": {"biped_controller.core.control.d"},
         "biped_sim.loose": set(), "biped_controller.core.loose": set()}
    v = room_violations(g, ROOMS)
    assert "biped_model.a (biped_model) imports biped_sim.plant.b (biped_sim.plant)" in v, v
    assert "biped_controller.core.qp.c (biped_controller.core.qp) imports biped_sim.plant.b (biped_sim.plant)" in v, v
    assert "biped_controller.core.qp.c (biped_controller.core.qp) imports biped_sim.graph.names (biped_sim.graph)" in v, v
    assert ("biped_controller.core.qp.c (biped_controller.core.qp) imports biped_controller.core.control.d "
            "(biped_controller.core.control)") in v, v
    assert ("biped_controller.core.sensing.e (biped_controller.core.sensing) imports biped_controller.core.control.d "
            "(biped_controller.core.control)") in v, v
    assert "biped_sim.loose is in no room" in v, v
    assert "biped_controller.core.loose is in no room" in v, v
    assert not any(s.startswith(("biped_sim.plant.b", "biped_controller.core.control.d", "biped_controller.gaits.f"))
                   for s in v), v


def test_rooms_import_only_the_rooms_below_them():
    assert room_violations(collect(PACKAGES), ROOMS) == []


# ------------------------------------------------------------------------------------------ the lab apart
#: top-level packages of the repository that are not the product: neither src/ nor tests/ imports them
OUTSIDE_PRODUCT = ("lab", "benchmarks")
TESTS = ROOT / "tests"


def files_imports(tests: Path) -> dict[str, set[str]]:
    """Every ``.py`` file under ``tests`` -> the modules it imports (anywhere in the file), keyed by its path
    relative to ``tests``' parent."""
    return {str(f.relative_to(tests.parent)): module_imports(f, f.stem) for f in sorted(tests.rglob("*.py"))}


def outside_imports(graph: dict[str, set[str]], outside=OUTSIDE_PRODUCT) -> list[str]:
    """``name imports X`` for each import in ``graph`` (module or file -> imported names) whose top-level
    package is one of ``outside``."""
    return [f"{m} imports {i}" for m, imps in sorted(graph.items()) for i in sorted(imps)
            if i.split(".")[0] in outside]


def test_lab_checker_finds_planted_imports(tmp_path):
    """Negative control: a synthetic product package and tests folder, each with an import of lab or
    benchmarks (one inside a function, one ``from X import``), are found; the clean files are not named."""
    pkg = tmp_path / "biped_sim"
    tests = tmp_path / "tests"
    pkg.mkdir()
    tests.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "clean.py").write_text("import numpy\nfrom . import other\n")
    (pkg / "other.py").write_text("def f():\n    from lab.sweep_check import replay\n")
    (tests / "test_clean.py").write_text("import subprocess\nARGS = ['-m', 'benchmarks.run']\n")
    (tests / "test_bad.py").write_text("from benchmarks import run\n\n\ndef test_x():\n    import lab\n")
    found = outside_imports(collect({"biped_sim": pkg})) + outside_imports(files_imports(tests))
    assert "biped_sim.other imports lab.sweep_check" in found, found
    assert "tests/test_bad.py imports benchmarks" in found and "tests/test_bad.py imports lab" in found, found
    assert not any(s.startswith(("biped_sim.clean", "tests/test_clean.py")) for s in found), found


def test_product_and_tests_import_neither_lab_nor_benchmarks():
    assert len(files_imports(TESTS)) >= 50
    assert outside_imports(collect(PACKAGES)) == []
    assert outside_imports(files_imports(TESTS)) == []
