"""Section 3 of ``scripts/bench``: DDS, the bare rclpy ping-pong between two processes and the nodes'
lockstep (simulator + controller, then the whole recorded graph) [steps/s], each in its own ROS domain."""
from __future__ import annotations

import importlib.util
import json
import subprocess
import sys

from benchmarks.common import ROOT
from benchmarks.domain import Domain


def bench_pingpong(count: int) -> dict:
    with Domain() as dom:
        pong = subprocess.Popen([sys.executable, "-m", "benchmarks.pingpong", "pong", "--timeout", "10"],
                                cwd=ROOT, env=dom.env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        try:
            p = subprocess.run([sys.executable, "-m", "benchmarks.pingpong", "ping", "--count", str(count),
                                "--warmup", "200"], cwd=ROOT, env=dom.env, capture_output=True, text=True,
                               timeout=120 + count / 100)
        finally:
            pong.terminate()
            try:
                pong.wait(5)
            except subprocess.TimeoutExpired:
                pong.kill()
                pong.wait()
        lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
        if p.returncode != 0 or not lines:
            return {"available": False, "error": (p.stdout + p.stderr)[-500:], "domain_id": dom.id}
        out = json.loads(lines[-1])
        out.update(available=True, domain_id=dom.id)
        return out


def bench_lockstep(seconds: float, pingpong: dict | None) -> dict:
    mods = ("biped_sim.graph.simulator_node", "biped_controller.graph.controller_node")
    missing = [m for m in mods if importlib.util.find_spec(m) is None]
    if missing:
        return {"available": False, "reason": f"not available: {', '.join(missing)} not written yet"}
    from benchmarks.lockstep import measure
    try:
        res = measure(seconds, Domain)
    except Exception as exc:  # noqa: BLE001
        return {"available": False, "reason": f"not available: {type(exc).__name__}: {exc}"}
    if res.get("available") and pingpong and pingpong.get("available"):
        res["fraction_of_pingpong"] = res["steps_per_s"] / pingpong["rate_hz"]
    from benchmarks.lockstep import measure_with_recorder
    try:
        res["with_recorder"] = measure_with_recorder(seconds, Domain)
    except Exception as exc:  # noqa: BLE001
        res["with_recorder"] = {"available": False, "reason": f"not available: {type(exc).__name__}: {exc}"}
    return res
