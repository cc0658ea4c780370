"""A robot's life cycle (``scripts/robot``): ``new``, ``build``, ``check``, ``list``.

- ``new NAME --from ROBOT [--set FIELD=VALUE ...]`` copies ROBOT's ``description.yaml`` (with the ``--set``
  fields changed, e.g. ``foot.length=0.1``) and writes its ``gait.yaml`` with the size-dependent settings
  derived from the new description (:func:`derive_gait_settings`, each with its reason), into
  ``robots/NAME`` (or the path NAME);
- ``build NAME|PATH`` optimises, fits and checks its gait family (progress on stdout) with the two-process
  build (:mod:`biped_controller.gaits.build`: the same file for any ``--workers``), stamps it with the
  description's hash and replaces ``gait_family.json`` atomically: an interrupted build leaves the previous
  family in place (an interrupted build resumes after its last complete phase: gaits.build's checkpoint);
  a family that fails its checks is not written unless ``--force``;
- ``check NAME|PATH`` the family's stamp, then its checks (fit at the fitted and the held-out strides,
  periodicity, the true-constraint margins and clearance between the strides);
- ``list`` every robot under ``robots/``: mass [kg], leg length [m], foot length [m], family;
- ``compare TABLE.json ... [--json FILE]`` max-push tables (``scripts/experiment table --robot NAME --json``)
  side by side, each boundary also as the dimensionless impulse F * duration / (M sqrt(g L)).

Bad input (a description with a missing, unknown or non-positive field, a torque limit that cannot hold the
robot standing, bad gait settings, a robot without a built family, a family built for another description):
one line ``scripts/robot: error: ...`` naming the field or the file, exit status 2, nothing written.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from biped_model.description import DescriptionError, RobotDescription, parse_description
from biped_model.gait_family import GaitFamily, GaitFamilyError
from biped_model.robot import (DESCRIPTION_FILE, FAMILY_FILE, GAIT_FILE, SETTINGS_FILE, STAMP_KEY, Robot, RobotError,
                               description_hash, is_path_spec, resolve_robot, robot_names)
from biped_model.settings import SettingsError, load_yaml_tree, robots_dir

from biped_controller.gaits import build, generation
from biped_controller.gaits.optimizer import GaitConfigError, StepOptimizer, load_gait_settings

PROG = "scripts/robot"
#: the values ``derive_gait_settings`` derives (gait.yaml keys)
DERIVED = ("step_duration", "preferred_stride", "strides", "smoothing_breakpoints", "zmp_margin", "initial_hip_height")
#: the default robot's initial-guess hip height [m] (gaits/optimizer.py, when gait.yaml does not give it)
BASE_HIP_HEIGHT = 0.74


class UsageError(ValueError):
    """Bad input: the message is one line naming the field or the file (exit status 2)."""


def _round(x: float) -> float:
    return float(round(x, 6))


def half_foot(desc: RobotDescription) -> float:
    """The shorter of heel and toe [m] (the ZMP's room on its narrower side of the ankle)."""
    return min(-desc.foot.l_min, desc.foot.l_max)


def derive_gait_settings(tree: dict, base: RobotDescription, desc: RobotDescription, base_name: str,
                         speed: float | None = None) -> dict:
    """The gait settings ``tree`` (a parsed gait.yaml of the robot ``base``) with the size-dependent values
    derived for ``desc``, each with its reason. Same Froude number v^2 / (g L) as ``base`` (L the leg
    length): strides, preferred stride and smoothing breakpoints scale with k = L / L_base, the step time
    with sqrt(k g_base / g) (so the speed scales with sqrt(k g / g_base)); the ZMP design margin keeps its
    fraction of the half-foot; the initial guess's hip height scales with k. With k = 1 and the same foot
    every value is ``base``'s, bit for bit. ``speed`` [m/s] given: the step time is the preferred stride over
    it instead (the strides still scale with k)."""
    k = desc.leg_length / base.leg_length
    kt = math.sqrt(k * base.gravity / desc.gravity)
    kf = half_foot(desc) / half_foot(base)
    out = dict(tree)
    src = f"{base_name}'s"
    T0 = float(tree["step_duration"]["value"])
    p0 = float(tree["preferred_stride"]["value"])
    hip0 = float(tree.get("initial_hip_height", {}).get("value", BASE_HIP_HEIGHT))
    T = _round(T0 * kt)
    froude = (p0 / T0) ** 2 / (base.gravity * base.leg_length)
    out["step_duration"] = {"value": T, "reason": (
        f"derived: {src} {T0} s x sqrt(k g_base / g) = x {kt:.6g} (k = leg length {desc.leg_length:g} / "
        f"{base.leg_length:g} m): the same Froude number v^2 / (g L) = {froude:.4g} as {base_name}")}
    if speed is not None:
        T = _round(_round(p0 * k) / speed)
        out["step_duration"] = {"value": T, "reason": (
            f"given: speed {speed:g} m/s (scripts/robot new --speed), T = preferred stride / speed; {base_name} "
            f"walks at the Froude number {froude:.4g}, this robot at {speed ** 2 / (desc.gravity * desc.leg_length):.4g}")}
    out["preferred_stride"] = {"value": _round(p0 * k), "reason": (
        f"derived: {src} {p0} m x k = {k:.6g} (strides scale with the leg length at the same Froude number); "
        f"speed {_round(p0 * k) / T:.4g} m/s")}
    out["strides"] = {"value": [_round(x * k) for x in tree["strides"]["value"]], "reason": (
        f"derived: {src} strides {tree['strides']['value'][0]}-{tree['strides']['value'][-1]} m x k = {k:.6g} "
        "(the same range in leg lengths, the preferred stride among them); the range the controller may use is "
        "what the build's held-out checks accept")}
    out["smoothing_breakpoints"] = {"value": [_round(x * k) for x in tree["smoothing_breakpoints"]["value"]],
                                    "reason": f"derived: {src} breakpoints x k = {k:.6g} (twice the stride spacing, "
                                              "the preferred stride among them, as for " + base_name + ")"}
    zm0 = float(tree["zmp_margin"]["value"])
    out["zmp_margin"] = {"value": _round(zm0 * kf), "reason": (
        f"derived: {src} {zm0} m x (half-foot {half_foot(desc):g} / {half_foot(base):g} m): the same fraction "
        f"({zm0 / half_foot(base):.3g}) of the shorter of heel and toe")}
    out["initial_hip_height"] = {"value": _round(hip0 * k), "reason": (
        f"derived: initial guess's hip height, {src} {hip0} m ({hip0 / base.leg_length:.4g} leg lengths) x k = {k:.6g}")}
    return out


#: the controller and simulator settings ``derive_robot_settings`` derives (a robot's settings.yaml)
DERIVED_SETTINGS = ("push_height", "observer_height", "mujoco_fall_hip_height", "mujoco_touch_threshold", "tau_dot_max")


def base_settings(base: Robot) -> dict:
    """The effective values of :data:`DERIVED_SETTINGS` for the robot ``base``: the configuration files'
    (``config/simulator.yaml``, ``config/controller.yaml``) under its own settings.yaml."""
    from biped_sim.plant.config import load_sim_config
    from biped_controller.core.control.config import load_controller_config
    own = dict(base.settings())
    sim = load_sim_config(**{k: v for k, v in own.items() if k in ("push_height", "mujoco_fall_hip_height",
                                                                   "mujoco_touch_threshold")})
    ctrl = load_controller_config(**{k: v for k, v in own.items() if k in ("observer_height", "tau_dot_max")})
    return {"push_height": sim.push_height, "observer_height": ctrl.observer_height,
            "mujoco_fall_hip_height": sim.mujoco_fall_hip_height, "mujoco_touch_threshold": sim.mujoco_touch_threshold,
            "tau_dot_max": ctrl.tau_dot_max}


def derive_robot_settings(values: dict, base: RobotDescription, desc: RobotDescription, T_base: float, T: float,
                          base_name: str) -> dict:
    """The size-dependent controller and simulator settings of ``desc`` from ``base``'s ``values``
    (:func:`base_settings`), ``{key: {value, reason}}``: the push and observer heights keep their place on
    the torso (a fraction of its centre of mass's height above the hip), MuJoCo's fall hip height its
    fraction of the leg length, the touch threshold its fraction of the weight, ``tau_dot_max`` (a tenth
    of a step per control period) scales with the step time. Equal to ``values`` when the two descriptions
    agree in those sizes."""
    k = desc.leg_length / base.leg_length
    kc = desc.torso.com / base.torso.com
    kw = desc.total_mass * desc.gravity / (base.total_mass * base.gravity)
    kT = T / T_base
    src = f"{base_name}'s"
    out = {}
    for key, factor, why in (
            ("push_height", kc, f"the torso's centre of mass above the hip ({desc.torso.com:g} m) x {src} "
                                f"{values['push_height']:g} / {base.torso.com:g} m"),
            ("observer_height", kc, f"the assumed height of the estimated force keeps its place on the torso: "
                                    f"{src} {values['observer_height']:g} m x {kc:.6g} (torso centre-of-mass height ratio)"),
            ("mujoco_fall_hip_height", k, f"a fall: hip below the same fraction of the leg length as {base_name} "
                                          f"({values['mujoco_fall_hip_height'] / base.leg_length:.4g} of {desc.leg_length:g} m)"),
            ("mujoco_touch_threshold", kw, f"a foot is loaded above the same fraction of the weight as for {base_name} "
                                           f"({values['mujoco_touch_threshold'] / (base.total_mass * base.gravity):.4g} of "
                                           f"{desc.total_mass * desc.gravity:.4g} N)"),
            ("tau_dot_max", kT, f"a tenth of a step per control period: {src} {values['tau_dot_max']:g} x step time "
                                f"ratio {kT:.6g}")):
        v = values[key] if factor == 1.0 else _round(values[key] * factor)
        out[key] = {"value": v, "reason": f"derived from the description: {why}"}
    return out


def _set_fields(tree: dict, items: list[str], base_name: str) -> dict:
    """``tree`` (a parsed description) with ``FIELD=VALUE`` items set (FIELD dotted, e.g. foot.length); the
    field must exist (an unknown one: :class:`UsageError` naming it)."""
    out = json.loads(json.dumps(tree))
    for item in items:
        key, sep, text = item.partition("=")
        if not sep:
            raise UsageError(f"--set expects FIELD=VALUE, got {item!r}")
        node = out
        parts = key.strip().split(".")
        for p in parts:
            if not isinstance(node, dict) or p not in node:
                raise UsageError(f"--set {key}: unknown field '{key}' of {DESCRIPTION_FILE}")
            node = node[p]
        if not isinstance(node, dict) or "value" not in node:
            raise UsageError(f"--set {key}: '{key}' is a group, not a value")
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise UsageError(f"--set {key}: the value does not parse: {exc}") from exc
        node["reason"] = f"set by scripts/robot new --set (was {node['value']} in {base_name}): {node.get('reason', '')}"
        node["value"] = value
    return out


def _target_dir(name: str) -> Path:
    return Path(name).expanduser() if is_path_spec(name) else robots_dir() / name


def _shown_path(path: Path) -> str:
    """``path`` as a file written into a robot shows it: relative to the robots' folder's parent (the
    repository) when it lies there, so no machine's absolute path is committed; absolute otherwise."""
    try:
        return str(Path(path).resolve().relative_to(robots_dir().resolve().parent))
    except ValueError:
        return str(path)


def cmd_new(name: str, source: str, items: list[str], speed: float | None = None) -> int:
    base = resolve_robot(source)
    base_desc = base.description()
    target = _target_dir(name)
    if target.exists():
        raise UsageError(f"{target}: exists already (choose another name)")
    tree = load_yaml_tree(base.description_path)
    new_tree = _set_fields(tree, items, base.name) if items else tree
    try:
        desc = parse_description(new_tree, source=str(target / DESCRIPTION_FILE))
    except DescriptionError as exc:
        raise UsageError(f"{target / DESCRIPTION_FILE}: {str(exc).removeprefix('biped description: ')}") from exc
    gait_tree = load_yaml_tree(base.gait_path)
    load_gait_settings(base.gait_path)                      # the source's settings are valid
    if speed is not None and not (math.isfinite(speed) and speed > 0):
        raise UsageError(f"--speed must be a finite number > 0 [m/s], got {speed}")
    derived = derive_gait_settings(gait_tree, base_desc, desc, base.name, speed)
    own = derive_robot_settings(base_settings(base), base_desc, desc, float(gait_tree["step_duration"]["value"]),
                                float(derived["step_duration"]["value"]), base.name)
    target.mkdir(parents=True)
    if items:
        head = (f"# Physical description of robot {target.name}: {base.name}'s ({_shown_path(base.description_path)}) with "
                f"{', '.join(items)} (scripts/robot new). Fields, units and frames: docs/robots.md\n")
        (target / DESCRIPTION_FILE).write_text(head + yaml.safe_dump(new_tree, sort_keys=False, width=120, default_flow_style=None),
                                               encoding="utf-8")
    else:
        shutil.copyfile(base.description_path, target / DESCRIPTION_FILE)
    head = (f"# Gait generation settings of robot {target.name}, from {base.name}'s (scripts/robot new): the "
            f"size-dependent values ({', '.join(DERIVED)}) derived from its description, each with its reason.\n")
    (target / GAIT_FILE).write_text(head + yaml.safe_dump(derived, sort_keys=False, width=120, default_flow_style=None), encoding="utf-8")
    head = (f"# Size-dependent controller and simulator settings of robot {target.name} (scripts/robot new, from "
            f"{base.name}): applied over config/controller.yaml and config/simulator.yaml, under a profile and --set.\n")
    (target / SETTINGS_FILE).write_text(head + yaml.safe_dump(own, sort_keys=False, width=120), encoding="utf-8")
    shown = ", ".join(f"{k}={_short(derived[k]['value'])}" for k in DERIVED)
    shown_own = ", ".join(f"{k}={own[k]['value']:g}" for k in DERIVED_SETTINGS)
    print(f"{target}: {DESCRIPTION_FILE} ({'from ' + base.name if not items else ', '.join(items)}), {GAIT_FILE} "
          f"(derived: {shown}), {SETTINGS_FILE} ({shown_own}); next: {PROG} build {name}")
    return 0


def _short(v) -> str:
    if isinstance(v, list):
        return f"[{v[0]:g}..{v[-1]:g}] ({len(v)})"
    return f"{v:g}"


def _check_inputs(r: Robot):
    """(description, gait settings) of ``r``, or :class:`UsageError` naming the file and field."""
    desc = r.description()
    if not r.gait_path.is_file():
        raise UsageError(f"{r.gait_path}: missing (the robot's gait settings)")
    try:
        st = load_gait_settings(r.gait_path)
    except (GaitConfigError, SettingsError) as exc:
        # (the settings reader names the default robot's file in some messages, and the file in others)
        why = str(exc).replace("robots/biped7/gait.yaml: ", "").replace(f"{r.gait_path}: ", "")
        raise UsageError(f"{r.gait_path}: {why}") from exc
    return desc, st


def warm_start(spec: str) -> np.ndarray:
    """The normalised coefficients (6, 5) of robot ``spec``'s step at its preferred stride (its family's
    stored record): the first guess of a build (``--warm-from``)."""
    w = resolve_robot(spec)
    w.check_stamp()
    data = json.loads(w.family_path.read_text(encoding="utf-8"))
    p_d = data["family"]["p_d"]
    for rec in data["strides"]:
        if rec["stride"] == p_d:
            return np.array(rec["c"], dtype=float)
    raise UsageError(f"{w.family_path}: no stored stride at p_d = {p_d}")


def cmd_build(spec: str, force: bool, speed_sweep: bool, warm_from: str | None = None, workers: int = 2,
              evaluator: str = "fast") -> int:
    r = resolve_robot(spec)
    desc, st = _check_inputs(r)
    first = warm_start(warm_from) if warm_from else None
    tmp = r.directory / f".{FAMILY_FILE}.{os.getpid()}.tmp"
    print(f"building the gait family of {r.name} ({r.directory}): {len(st.strides)} strides "
          f"{st.strides[0]:g}-{st.strides[-1]:g} m, p_d {st.p_d:g} m, T {st.T:g} s, {len(st.smoothing_weights)} "
          f"smoothing passes, at most {st.max_iterations} iterations per solve, the two-process build "
          f"(biped_controller.gaits.build, {workers} worker(s), evaluator {evaluator}; an interrupted build resumes "
          f"after its last complete phase from {build.checkpoint_path(r.family_path).name}; the previous {FAMILY_FILE} "
          f"stays until this one is complete)",
          flush=True)
    # the preferred stride first, on its own: without a gait there, no family (one line naming the binding
    # constraint, not a solver trace); with one, the generator starts there (converged at once)
    t0 = time.perf_counter()
    sol = StepOptimizer(desc=desc, settings=st).solve(st.p_d, c0=first)
    print(f"preferred stride p_d = {st.p_d:g} m: {'feasible' if sol.success else 'NO GAIT'}, criterion "
          f"{sol.criterion:.1f}, smallest margin {sol.min_margin:.3g} ({sol.min_margin_name}), "
          f"{time.perf_counter() - t0:.0f} s", flush=True)
    if not sol.success:
        print(f"{PROG}: no feasible gait for {r.name} at p_d = {st.p_d:g} m, T = {st.T:g} s: the constraint that binds "
              f"is {sol.min_margin_name} (margin {sol.min_margin:.3g}; solver: {sol.message}); "
              f"{r.family_path} not written (docs/robots.md, 'When the build finds no gait')", file=sys.stderr)
        return 1
    try:
        t1 = time.perf_counter()
        data, times = build.build_family(st, desc=desc, workers=workers, evaluator=evaluator, progress=True,
                                         speed=speed_sweep, first_guess=sol.c,
                                         checkpoint=build.checkpoint_path(r.family_path))
        # the stamp as generation.generate writes it (the description this family was built for)
        data[STAMP_KEY] = {"description_sha256": description_hash(desc)}
        print(f"family: {times['family']:.1f} s, total {time.perf_counter() - t1:.1f} s ({workers} worker(s), "
              f"evaluator {evaluator}, single-threaded BLAS)", flush=True)
        validation = data["validation"]
        generation.print_report(data, validation)
        ok, why = generation.within_tolerance(validation, st)
        for w in why:
            print(f"NOT ACCEPTED: {w}")
        if not ok and not force:
            print(f"{r.family_path}: not replaced (the new family fails its checks; --force writes it anyway)")
            return 1
        if data[STAMP_KEY]["description_sha256"] != r.description_hash():    # (the generator's own stamp)
            raise UsageError(f"{r.description_path} changed during the build: {r.family_path} not replaced")
        data[STAMP_KEY] = {"description_sha256": r.description_hash(), "description": DESCRIPTION_FILE,
                           "settings": GAIT_FILE, "accepted": ok}
        tmp.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n", encoding="utf-8")
        os.replace(tmp, r.family_path)
        if r.stamp_path.is_file():          # the sidecar stamped the previous file only
            r.stamp_path.unlink()
        print(f"{r.family_path}: written, stamped {r.description_hash()[:12]}" + ("" if ok else " (--force: NOT ACCEPTED)"))
        return 0 if ok else 1
    finally:
        if tmp.exists():
            tmp.unlink()


def cmd_check(spec: str) -> int:
    r = resolve_robot(spec)
    desc, st = _check_inputs(r)
    h = r.check_stamp()
    data = json.loads(r.family_path.read_text(encoding="utf-8"))
    try:
        fam = GaitFamily.load(r.family_path)
    except GaitFamilyError as exc:
        raise UsageError(str(exc)) from exc
    opt = StepOptimizer(desc=desc, settings=st)
    validation = generation.check_family(fam, data["strides"], opt, data.get("held_out", []))
    validation["fit_range"] = list(fam.meta.get("fit_range", [])) or [fam.p_min, fam.p_max]
    generation.print_report(data, validation)
    ok, why = generation.within_tolerance(validation, st)
    for w in why:
        print(f"NOT ACCEPTED: {w}")
    print(f"{r.name}: stamp {h[:12]} matches {r.description_path}; checks {'passed' if ok else 'FAILED'}")
    return 0 if ok else 1


def family_state(r: Robot) -> str:
    if not r.has_family():
        return "not built"
    try:
        r.check_stamp()
    except RobotError:
        return "stale (built for another description)"
    fam = GaitFamily.load(r.family_path)
    return f"built [{fam.p_min:g}, {fam.p_max:g}] m"


def cmd_list() -> int:
    print(f"{'robot':<16} {'mass [kg]':>9} {'leg [m]':>8} {'foot [m]':>8}  family")
    for name in robot_names():
        r = resolve_robot(name)
        try:
            d = r.description()
        except RobotError as exc:
            print(f"{name:<16} {'-':>9} {'-':>8} {'-':>8}  (description: {exc})")
            continue
        print(f"{name:<16} {d.total_mass:9.3g} {d.leg_length:8.3g} {d.foot.length:8.3g}  {family_state(r)}")
    return 0


def _table_meta(path: Path) -> tuple[str, str, float]:
    """(robot, plant, push duration [s]) of a ``scripts/experiment table --json`` file, from its ``argv``."""
    from biped_controller.studies.trial.runs import DEFAULT_DURATION
    data = json.loads(Path(path).read_text(encoding="utf-8"))
    argv = [str(a) for a in data.get("argv", [])]

    def opt(name: str, default: str) -> str:
        return argv[argv.index(name) + 1] if name in argv and argv.index(name) + 1 < len(argv) else default
    plant = "mujoco" if any(a.replace(" ", "") == "plant=mujoco" for a in argv) else "rigid"
    return opt("--robot", "") or "biped7", plant, float(opt("--duration", str(DEFAULT_DURATION)))


def compare_tables(paths: list[Path]) -> dict:
    """Max-push tables of several robots side by side: per (robot, plant) each mode's largest survived
    push ``max_force`` [N] and the same boundary as a dimensionless impulse F * duration / (M sqrt(g L)),
    M the robot's total mass, L its leg length (thigh + shin).

    Several tables of one robot on one plant (e.g. the paper's modes in one run, a registered controller such
    as ``dcm_wbc`` in another) merge into one row, each mode naming the table it came from (``table``). They
    must share the push duration, and a mode found in two of them must give the same ``max_force`` (the
    searches are deterministic); otherwise :class:`UsageError` names both files."""
    rows: list[dict] = []
    by: dict[str, int] = {}
    for path in paths:
        robot, plant, dt = _table_meta(path)
        d = resolve_robot(robot).description()
        scale = d.total_mass * math.sqrt(d.gravity * d.leg_length)
        modes = json.loads(Path(path).read_text(encoding="utf-8"))["modes"]
        key = f"{robot}/{plant}"
        if key not in by:
            by[key] = len(rows)
            rows.append({"table": str(path), "tables": [], "robot": robot, "plant": plant, "duration": dt,
                         "mass": d.total_mass, "leg_length": d.leg_length, "foot_length": d.foot.length,
                         "impulse_scale": scale, "modes": {}})
        row = rows[by[key]]
        if dt != row["duration"]:
            raise UsageError(f"{path}: push duration {dt} s, but {row['tables'][0]} has {row['duration']} s "
                             f"({key})")
        row["tables"].append(str(path))
        for m, r in modes.items():
            old = row["modes"].get(m)
            if old is not None:
                if old["max_force"] != r["max_force"]:
                    raise UsageError(f"{path}: mode {m} max_force {r['max_force']} N, but {old['table']} gives "
                                     f"{old['max_force']} N ({key})")
                continue
            row["modes"][m] = {"max_force": r["max_force"], "table": str(path),
                               "impulse": None if r["max_force"] is None else r["max_force"] * dt / scale}
    return {"definition": "impulse = max_force * duration / (mass * sqrt(g * leg_length)), dimensionless",
            "rows": rows, "by": by}


def cmd_compare(paths: list[Path], out: Path | None) -> int:
    for p in paths:
        if not Path(p).is_file():
            raise UsageError(f"{p}: missing (a scripts/experiment table --json file)")
    data = compare_tables(paths)
    modes = list(dict.fromkeys(m for r in data["rows"] for m in r["modes"]))
    print(f"{'robot':<16} {'plant':<7} {'M [kg]':>6} {'L [m]':>6} {'foot':>5}  " + "  ".join(f"{m:>20}" for m in modes))
    for r in data["rows"]:
        cells = []
        for m in modes:
            c = r["modes"].get(m)
            cells.append(f"{'-':>20}" if c is None or c["max_force"] is None else f"{c['max_force']:9.3f} N {c['impulse']:.4f}")
        print(f"{r['robot']:<16} {r['plant']:<7} {r['mass']:6.1f} {r['leg_length']:6.3f} {r['foot_length']:5.2f}  " + "  ".join(cells))
    if out is not None:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps(data, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("new", help="a new robot from an existing one's description and settings")
    a.add_argument("name", help="a name under robots/ or a path")
    a.add_argument("--from", dest="source", default="", metavar="ROBOT", help="the robot to start from (default biped7)")
    a.add_argument("--set", dest="items", action="append", default=[], metavar="FIELD=VALUE",
                   help="a description field changed, e.g. foot.length=0.1 (repeatable; docs/robots.md)")
    a.add_argument("--speed", type=float, default=None, metavar="M_PER_S",
                   help="the preferred walking speed [m/s] (default: the source robot's Froude number)")
    a = sub.add_parser("build", help="build the robot's gait family (atomic replace)")
    a.add_argument("robot", metavar="NAME|PATH")
    a.add_argument("--force", action="store_true", help="write the family even when it fails its checks")
    a.add_argument("--no-speed-sweep", action="store_true", help="leave out the 1 m/s stride sweep (speed_1mps)")
    a.add_argument("--warm-from", default=None, metavar="ROBOT",
                   help="start the preferred stride's solve from ROBOT's step there instead of the stated initial "
                        "guess (a robot close to ROBOT builds faster)")
    a.add_argument("--workers", type=int, default=2, metavar="N",
                   help="worker processes of the build (1: everything in this process; the same file for any N)")
    a.add_argument("--evaluator", choices=build.EVALUATORS, default="fast",
                   help="fast (exact impact-map derivative, default) or reference (generation.generate's numbers "
                        "under single-threaded BLAS)")
    a = sub.add_parser("check", help="the family's stamp and checks")
    a.add_argument("robot", metavar="NAME|PATH")
    sub.add_parser("list", help="the robots under robots/")
    a = sub.add_parser("compare", help="max-push tables of several robots side by side, also as dimensionless impulses")
    a.add_argument("tables", nargs="+", type=Path, metavar="TABLE.json", help="scripts/experiment table --json files")
    a.add_argument("--json", type=Path, default=None, help="write the comparison here")
    args = ap.parse_args(argv)
    if args.cmd == "compare":
        from biped_controller.studies import provenance
        provenance.track(args.json, argv=argv)
    try:
        if args.cmd == "new":
            return cmd_new(args.name, args.source, args.items, args.speed)
        if args.cmd == "build":
            if args.workers < 1:
                raise UsageError(f"--workers must be >= 1, got {args.workers}")
            return cmd_build(args.robot, args.force, not args.no_speed_sweep, args.warm_from, args.workers,
                             args.evaluator)
        if args.cmd == "check":
            return cmd_check(args.robot)
        if args.cmd == "compare":
            return cmd_compare(args.tables, args.json)
        return cmd_list()
    except (UsageError, RobotError, SettingsError, GaitConfigError) as exc:
        print(f"{PROG}: error: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
