"""DDS lockstep of the real nodes: biped_sim.graph.simulator_node + biped_controller.graph.controller_node.

Both are started as subprocesses in an isolated domain (no recorder: wait_for_recorder false), walk a
short run (max_time sim seconds), and the rate is read from the simulator's own end-of-run log line
``run over: ...; N control steps, ... wall W s (R steps/s)`` (its wall clock starts at the first
published state, so discovery and start-up are excluded).
"""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from benchmarks import common

ROOT = Path(__file__).resolve().parents[1]
_LINE = re.compile(r"run over: (?P<reason>[^;]*); (?P<steps>\d+) control steps, sim time (?P<sim>[0-9.]+) s, "
                   r"(?P<imp>\d+) impacts, wall (?P<wall>[0-9.]+) s")


def measure(sim_seconds: float, domain_cls, timeout: float = 180.0, ctrl_params: tuple[str, ...] = (),
            sim_params: tuple[str, ...] = ()) -> dict:
    """The lockstep rate; ``ctrl_params`` / ``sim_params``: more ``NAME:=VALUE`` parameters of the controller /
    simulator node."""
    extra = [a for p in ctrl_params for a in ("-p", p)]
    sim_extra = [a for p in sim_params for a in ("-p", p)]
    with domain_cls() as dom:
        ctrl = subprocess.Popen([sys.executable, "-m", "biped_controller.graph.controller_node", "--ros-args",
                                 "-p", "use_sim_time:=true", "-p", "wait_for_recorder:=false", *extra],
                                cwd=ROOT, env=dom.env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            sim = subprocess.run([sys.executable, "-m", "biped_sim.graph.simulator_node", "--ros-args",
                                  "-p", "wait_for_recorder:=false", "-p", "max_steps:=0",
                                  "-p", f"max_time:={sim_seconds}", "-p", "linger:=0.0",
                                  "-p", "start_delay:=0.5", *sim_extra],
                                 cwd=ROOT, env=dom.env, capture_output=True, text=True, timeout=timeout)
        finally:
            ctrl.terminate()
            try:
                out_c, _ = ctrl.communicate(timeout=10)
            except subprocess.TimeoutExpired:
                ctrl.kill()
                out_c, _ = ctrl.communicate()
        text = sim.stdout + sim.stderr
        m = _LINE.search(text)
        if sim.returncode != 0 or m is None:
            return {"available": False, "reason": f"not available: simulator_node exit {sim.returncode}: "
                    + text[-300:].replace("\n", " | "), "controller_log_tail": (out_c or "")[-300:]}
        steps, wall, simt = int(m["steps"]), float(m["wall"]), float(m["sim"])
        return {"available": True, "end_reason": m["reason"], "steps": steps, "wall_s": wall, "sim_s": simt,
                "impacts": int(m["imp"]), "steps_per_s": steps / wall, "realtime_factor": simt / wall,
                "domain_id": dom.id}


def measure_with_recorder(sim_seconds: float, domain_cls, timeout: float = 300.0) -> dict:
    """The same rate with the whole recorded graph, as the product runs it: ``biped_sim.graph.launch`` (recorder,
    controller, disturbance, simulator; the bag in a temporary directory), rate from the simulator's line."""
    import tempfile
    with domain_cls() as dom, tempfile.TemporaryDirectory() as tmp:
        p = subprocess.run([sys.executable, "-m", "biped_sim.graph.launch", "--bag", str(Path(tmp) / "bag"), "--steps", "0",
                            "--sim-param", f"max_time:={sim_seconds}", "--sim-param", "linger:=0.0"]
                           + (["--robot", common.SETTINGS.robot] if common.SETTINGS is not None and common.SETTINGS.robot else []),
                           cwd=ROOT, env=dom.env, capture_output=True, text=True, timeout=timeout)
        text = p.stdout + p.stderr
        m = _LINE.search(text)
        if p.returncode != 0 or m is None:
            return {"available": False, "reason": f"not available: launch exit {p.returncode}: "
                    + text[-300:].replace("\n", " | ")}
        steps, wall, simt = int(m["steps"]), float(m["wall"]), float(m["sim"])
        return {"available": True, "end_reason": m["reason"], "steps": steps, "wall_s": wall, "sim_s": simt,
                "steps_per_s": steps / wall, "realtime_factor": simt / wall}
