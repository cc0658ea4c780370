"""The demo over DDS: ``python -m biped_sim.graph.demo [--steps N] [--force F] [--duration D] [--start T]
[--bag DIR] [--json FILE] [--live [--port N]] [--ctrl-param KEY:=VALUE ...] [--sim-param KEY:=VALUE ...]``.

1. launches the node graph (``biped_sim.graph.launch``) with the bag under ``runs/demo_<timestamp>/``; the
   simulator is started paused (``wait_for_pushes:=1``) so that sim time cannot run past the push;
2. calls ``/apply_push`` (default 250 N for 0.025 s at t = 0.2315 s, the middle of the first step);
3. waits for the run (default 10 steps, or a fall) and the graph's clean stop;
4. reads the bag back (``bag_reader``) and prints a summary: survived or fell and why, max |l| (the
   simulator's centre of pressure), p and tau excursions, message counts per topic, MCAP path and
   size, wall time, lockstep steps/s. ``--json FILE`` writes the summary too.

``--live``: the launcher also starts the Foxglove WebSocket bridge (``launch --live``: simulator paced
at real time); connect Foxglove to ``ws://localhost:8765`` (or ``--port N``). The run starts as soon as
the push is accepted; a client that connects later gets the latched ``/robot_description`` and
follows from then on.

``--ctrl-param KEY:=VALUE`` (repeatable): a controller parameter, passed to the launcher's ``--ctrl-param``,
e.g. a policy as the controller: ``--ctrl-param controller:=onnx_policy --ctrl-param
"controller_options:=['file=PATH']"`` (docs/policies.md). ``--sim-param KEY:=VALUE`` (repeatable): a simulator
parameter, passed to the launcher's ``--sim-param``, e.g. ``plant:=mujoco``.

Exit status 0 when the demo ran (whatever the robot did); 1 when the graph or the push failed.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from biped_sim.recording.bag_summary import summarize_bag


def print_summary(s: dict) -> None:
    def f(x, fmt='{:.4f}'):
        return 'n/a' if x is None else fmt.format(x)
    print('==== demo summary ====')
    if s['outcome'] == 'fell':
        print(f"outcome: FELL at t = {f(s['fall_time'])} s: {s['fall_cause']} ({s['fall_detail']})")
    else:
        print(f"outcome: survived ({s['steps_walked']} steps walked)")
    for p in s['pushes']:
        print(f"push {p['id']}: {p['force']} N over [{p['start']}, {p['start'] + p['duration']}) s at {p['height']} m")
    print(f"control steps {s['control_steps']}, sim time {f(s['sim_time'], '{:.3f}')} s")
    print(f"max |l| (simulator CoP) {f(s['max_abs_cop_l'])} m (limit 0.1); controller zmp max "
          f"{f(s['max_abs_zmp_controller'])} m")
    for k in ('p_range', 'p_dot_range', 'tau_range', 'tau_dot_range'):
        v = s[k]
        print(f"{k[:-6]}: [{f(v[0]) if v else 'n/a'}, {f(v[1]) if v else 'n/a'}]")
    print(f"max tracking error {f(s['max_tracking_error'])} rad; last qp_status {s['last_qp_status']} "
          f"({s['last_qp_message'] or 'no message'}), {s['qp_fallback_steps']} steps with a QP fallback")
    print('messages per topic:')
    for t, n in s['counts'].items():
        print(f'  {t:24s} {n}')
    print(f"MCAP {s['mcap_path']}: {s['mcap_bytes']} B ({f(s['mcap_bytes_per_sim_second'], '{:.0f}')} B per sim second)")
    print(f"wall time {f(s.get('wall_time'), '{:.2f}')} s (lockstep part {f(s['lockstep_wall_time'], '{:.2f}')} s), "
          f"lockstep {f(s['lockstep_steps_per_second'], '{:.0f}')} steps/s")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='demo', description='Push demo over the ROS 2 node graph.')
    ap.add_argument('--steps', type=int, default=10)
    ap.add_argument('--force', type=float, default=250.0)
    ap.add_argument('--duration', type=float, default=0.025)
    ap.add_argument('--start', type=float, default=0.2315, help='sim time of the push onset [s]')
    ap.add_argument('--bag', type=Path, default=None)
    ap.add_argument('--json', type=Path, default=None)
    ap.add_argument('--timeout', type=float, default=600.0, help='wall s for the whole run')
    ap.add_argument('--live', action='store_true', help='Foxglove WebSocket bridge, real-time pacing')
    ap.add_argument('--port', type=int, default=None, help='--live: WebSocket port (default 8765)')
    ap.add_argument('--ctrl-param', action='append', default=[], metavar='KEY:=VALUE',
                    help="extra controller parameter, passed to the launcher's --ctrl-param (repeatable), e.g. "
                         "controller:=onnx_policy and \"controller_options:=['file=PATH']\" (docs/policies.md)")
    ap.add_argument('--sim-param', action='append', default=[], metavar='KEY:=VALUE',
                    help="extra simulator parameter, passed to the launcher's --sim-param (repeatable), e.g. "
                         "plant:=mujoco")
    ap.add_argument('--robot', default=None, metavar='NAME|PATH',
                    help="the robot: a name under robots/ or a robot directory's path (default biped7; docs/robots.md)")
    a = ap.parse_args(argv)
    if a.robot is not None:         # one line naming the file, exit 2, before the graph starts
        from biped_model.robot import RobotError, resolve_robot
        try:
            r = resolve_robot(a.robot)
            r.description()
            r.check_stamp()
        except RobotError as exc:
            print(f'demo: {exc}', file=sys.stderr)
            return 2
    from biped_model.settings import repo_root
    bag = (a.bag or repo_root() / 'runs' / f'demo_{_dt.datetime.now().strftime("%Y%m%d_%H%M%S")}').resolve()
    bag.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        ready = Path(tmp) / 'ready'
        cmd = [sys.executable, '-m', 'biped_sim.graph.launch', '--bag', str(bag), '--steps', str(a.steps),
               '--sim-param', 'wait_for_pushes:=1', '--ready-file', str(ready)]
        if a.robot is not None:
            cmd += ['--robot', a.robot]
        for kv in a.ctrl_param:
            cmd += ['--ctrl-param', kv]
        for kv in a.sim_param:
            cmd += ['--sim-param', kv]
        if a.live:
            cmd += ['--live'] + (['--port', str(a.port)] if a.port is not None else [])
        launcher = subprocess.Popen(cmd)
        forwarded = {'n': 0}

        def forward(signum, _frame):
            forwarded['n'] += 1
            if launcher.poll() is None:
                launcher.send_signal(signum)

        prev = {s: signal.signal(s, forward) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            while not ready.exists() and launcher.poll() is None and time.monotonic() - t0 < 120:
                time.sleep(0.05)
            if launcher.poll() is not None or not ready.exists():
                print('demo: the graph did not come up', file=sys.stderr)
                launcher.send_signal(signal.SIGINT)
                launcher.wait(60)
                return 1
            from biped_sim.graph.push_client import call_apply_push, response_dict
            try:
                res = call_apply_push(a.force, a.duration, start=a.start, timeout=30.0)
            except TimeoutError as exc:
                print(f'demo: {exc}', file=sys.stderr)
                launcher.send_signal(signal.SIGINT)
                launcher.wait(60)
                return 1
            print(f'demo: /apply_push -> {response_dict(res)}', flush=True)
            if not res.accepted:
                launcher.send_signal(signal.SIGINT)
                launcher.wait(60)
                return 1
            try:
                rc = launcher.wait(a.timeout)
            except subprocess.TimeoutExpired:
                print(f'demo: run longer than {a.timeout} s: stopping', file=sys.stderr)
                launcher.send_signal(signal.SIGINT)
                rc = launcher.wait(60)
        finally:
            for s, h in prev.items():
                signal.signal(s, h)
    wall = time.monotonic() - t0
    if rc != 0:
        print(f'demo: the launcher exited with {rc}', file=sys.stderr)
    try:
        summary = summarize_bag(bag)
    except Exception as exc:  # noqa: BLE001 - report any reading problem plainly
        print(f'demo: cannot read the bag {bag}: {exc}', file=sys.stderr)
        return 1
    summary['wall_time'] = wall
    summary['launcher_exit_code'] = rc
    summary['bag'] = str(bag)
    print_summary(summary)
    if a.json:
        a.json.write_text(json.dumps(summary, indent=2) + '\n')
        print(f'summary written to {a.json}')
    return 0 if rc == 0 else 1


if __name__ == '__main__':
    sys.exit(main())
