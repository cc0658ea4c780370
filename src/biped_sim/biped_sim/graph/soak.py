"""Soak run over DDS: ``python -m biped_sim.graph.soak [--minutes N] [--json FILE] [--seed S] [--bag DIR]
[--robot NAME|PATH]``.

1. launches the node graph (``biped_sim.graph.launch``, ``--steps 0``, simulator ``max_time`` = N minutes of
   sim time) with the bag under ``runs/soak_<timestamp>/``;
2. while it walks, requests pushes through ``/apply_push``: a seeded plan (``push_plan``) of pushes every
   ``--every`` sim seconds (uniform in [every/2, 3 every/2]), alternating random directions, magnitudes
   uniform in [--min-force, --max-forward] forward and [--min-force, --max-backward] backward,
   0.025 s each; each one is requested about ``--lead`` sim seconds before its planned onset, sim time
   being read from ``/clock`` (keep-last 1, sampled a few times per wall second), in the service's delay
   form: onset = the disturbance node's own sim time when it receives the request + ``delay``, with
   ``delay`` = planned onset - the sim time seen here, at least ``--min-lead``. A request therefore
   cannot arrive late ("start must not be in the past"), however far the graph moved on since this
   process read ``/clock`` (a loaded machine); the push acts at the onset the service answers
   (``scheduled_start``, >= the planned one when this process lags), which the checks use. The simulator
   is paced at ``--real-time-factor`` (default 1.0: the lockstep graph runs ~5x faster than real time
   unpaced);
3. samples VmRSS (``/proc/<pid>/status``) of each node process every ``--mem-every`` sim seconds;
4. after the run, checks from the MCAP alone (``analyze_bag``): the ``/sim/state`` sequence has no gap
   or repeat, every per-step topic holds exactly the states' stamps (the period-topics all but the
   final state's), every requested push appears once in ``/push_events`` and ``/push_requests``, its
   effect on the state is its impulse (whole-body horizontal momentum change minus the ground's
   horizontal impulse, within 10 % of F d; pushes with an impact inside the window are reported as not
   checkable), no fall; and that each node's resident memory grew less than 10 % between minute 1
   (or half the run when shorter) and the end.

Prints a summary, ``--json FILE`` writes it. Exit 0 when every check passed, 1 otherwise.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path


from biped_sim.recording.bag_summary import analyze_bag

PUSH_DURATION = 0.025
# [s] between one push's end and the next one's onset when the requester fell behind: one control period,
# far above the rounding of the service's now + delay, far below the plan's spacing (every x 0.5)
SEPARATION = 1e-3
NODE_NAMES = ('simulator', 'controller', 'disturbance', 'recorder')
MEMORY_GROWTH_LIMIT = 0.10


# ----------------------------------------------------------------------------- plan
def robot_force_scale(robot: str | None) -> float:
    """The ratio of ``robot``'s M sqrt(g L) to the default robot's (M total mass [kg], L leg length [m]):
    a push of the same dimensionless impulse F dt / (M sqrt(g L)) is this many times the default robot's
    force. Exactly 1.0 for the default robot (or None). Raises ``RobotError`` naming a robot that cannot be
    used (its directory, its description or its family's stamp)."""
    from biped_model.description import load_description
    from biped_model.robot import description_hash, resolve_robot
    if robot is None:
        return 1.0
    r = resolve_robot(robot)
    d, b = r.description(), load_description()
    r.check_stamp()
    if description_hash(d) == description_hash(b):
        return 1.0
    return (d.total_mass * math.sqrt(d.gravity * d.leg_length)) / (b.total_mass * math.sqrt(b.gravity * b.leg_length))


def push_plan(total_time: float, seed: int, every: float = 3.0, min_force: float = 80.0,
              max_forward: float = 150.0, max_backward: float = 150.0, first: float = 5.0,
              tail: float = 1.5) -> list[dict]:
    """Seeded pushes over [first, total_time - tail): ``[{start, duration, force}]``, starts on the
    1 us grid, consecutive starts ``every`` * U(0.5, 1.5) apart, signs random. ``first`` leaves the
    requester time to find ``/apply_push`` once the graph runs (a slow discovery on a loaded machine
    must not make the first request late: each is made ~1 sim s ahead)."""
    rng = random.Random(seed)
    out = []
    t = first + rng.uniform(0.0, every)
    while t < total_time - tail:
        forward = rng.random() < 0.5
        mag = rng.uniform(min_force, max_forward if forward else max_backward)
        out.append({'start': round(t, 6), 'duration': PUSH_DURATION,
                    'force': round(mag if forward else -mag, 3)})
        t += every * rng.uniform(0.5, 1.5)
    return out


# ----------------------------------------------------------------------------- processes
def descendants(pid: int) -> list[int]:
    """Every descendant process of ``pid`` (from /proc/<pid>/task/<pid>/children, recursively)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        try:
            with open(f'/proc/{p}/task/{p}/children') as fh:
                kids = [int(x) for x in fh.read().split()]
        except OSError:
            kids = []
        out += kids
        todo += kids
    return out


def node_pids(launcher_pid: int) -> dict[str, int]:
    """node name -> pid of the launcher's children running ``lib/<pkg>/<node>``."""
    found = {}
    for p in descendants(launcher_pid):
        try:
            with open(f'/proc/{p}/cmdline', 'rb') as fh:
                argv = fh.read().split(b'\0')
        except OSError:
            continue
        for a in argv[:3]:
            base = os.path.basename(a.decode(errors='replace'))
            if base in NODE_NAMES and b'/lib/' in a:
                found.setdefault(base, p)
    return found


def vm_rss_kb(pid: int) -> int | None:
    try:
        with open(f'/proc/{pid}/status') as fh:
            for line in fh:
                if line.startswith('VmRSS:'):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


# ----------------------------------------------------------------------------- bag analysis
def _log(msg: str) -> None:
    print(f'soak: {msg}', file=sys.stderr, flush=True)


def push_delay(planned_start: float, seen_sim_time: float, min_lead: float, not_before: float = -math.inf) -> float:
    """The ``delay`` [s] of a relative ``/apply_push`` request for a push planned at ``planned_start`` (sim s),
    made when this process last saw sim time ``seen_sim_time``: the time left until the planned onset, at least
    ``min_lead`` (the service adds it to its own, later or equal, sim time, so the onset is never in the past
    and the simulator gets the event before the onset), and at least until ``not_before`` (sim s: the end of
    the push accepted before, so that a requester that fell behind and asks for two pushes in a row never
    asks for overlapping ones: the onset is the service's now + delay >= seen + delay >= not_before)."""
    if not (math.isfinite(planned_start) and math.isfinite(seen_sim_time)) or not min_lead > 0 \
            or math.isnan(not_before):
        raise ValueError(f'push_delay: finite times and min_lead > 0 needed, got {planned_start}, '
                         f'{seen_sim_time}, {min_lead}, {not_before}')
    return max(min_lead, planned_start - seen_sim_time, not_before - seen_sim_time)


def run_soak(minutes: float, bag: Path, seed: int = 1, every: float = 3.0, min_force: float = 80.0,
             max_forward: float = 150.0, max_backward: float = 150.0, lead: float = 1.0, min_lead: float = 0.5,
             mem_every: float = 10.0, timeout: float | None = None, real_time_factor: float = 1.0,
             robot: str | None = None) -> dict:
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy, DurabilityPolicy, HistoryPolicy
    from rclpy.signals import SignalHandlerOptions
    from rosgraph_msgs.msg import Clock

    from biped_msgs_py.srv import ApplyPush
    from biped_sim.graph import names as gn

    total = 60.0 * minutes
    plan = push_plan(total, seed, every, min_force, max_forward, max_backward)
    mem_first_at = min(60.0, total / 2)
    wall_timeout = timeout if timeout is not None else 600.0 + total * 30.0
    t0 = time.monotonic()
    result: dict = {'minutes': minutes, 'sim_seconds': total, 'seed': seed, 'bag': str(bag),
                    'plan': plan, 'requested': [], 'memory': [], 'problems': []}
    with tempfile.TemporaryDirectory() as tmp:
        ready = Path(tmp) / 'ready'
        cmd = [sys.executable, '-m', 'biped_sim.graph.launch', '--bag', str(bag), '--steps', '0',
               '--sim-param', f'max_time:={total}', '--sim-param', 'linger:=1.0',
               '--sim-param', f'real_time_factor:={real_time_factor}', '--ready-file', str(ready)]
        if robot is not None:
            cmd += ['--robot', str(robot)]
        launcher = subprocess.Popen(cmd)
        ctx = rclpy.Context()
        rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
        node = rclpy.create_node('soak_probe', context=ctx, start_parameter_services=False)
        latest = {'t': -1.0}
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
        node.create_subscription(Clock, gn.CLOCK, lambda m: latest.__setitem__(
            't', m.clock.sec + 1e-9 * m.clock.nanosec), qos)
        client = node.create_client(ApplyPush, gn.APPLY_PUSH)
        from rclpy.executors import SingleThreadedExecutor
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        stop = {'sig': None}
        prev = {s: signal.signal(s, lambda signum, _f: stop.__setitem__('sig', signum))
                for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            while not ready.exists():
                if launcher.poll() is not None or time.monotonic() - t0 > 180 or stop['sig']:
                    raise RuntimeError('the graph did not come up')
                time.sleep(0.05)
            if not client.wait_for_service(timeout_sec=60):
                raise RuntimeError(f'{gn.APPLY_PUSH} not available')
            next_push = 0
            not_before = -math.inf     # sim s: the end of the last accepted push plus one control period
            next_mem = mem_first_at
            final_sampled = False
            while launcher.poll() is None:
                if stop['sig'] is not None:
                    raise RuntimeError(f'stopped by signal {stop["sig"]}')
                if time.monotonic() - t0 > wall_timeout:
                    raise RuntimeError(f'soak longer than {wall_timeout} s wall')
                # take the latest /clock (keep-last 1): a few spins, no busy loop
                for _ in range(3):
                    ex.spin_once(timeout_sec=0.0)
                now = latest['t']
                if next_push < len(plan) and now >= plan[next_push]['start'] - lead:
                    p = plan[next_push]
                    delay = push_delay(p['start'], now, min_lead, not_before)
                    req = ApplyPush.Request(force=float(p['force']), duration=float(p['duration']),
                                            start=0.0, use_delay=True, delay=delay, height=math.nan)
                    fut = client.call_async(req)
                    ex.spin_until_future_complete(fut, timeout_sec=30.0)
                    res = fut.result() if fut.done() else None
                    accepted = bool(res and res.accepted)
                    # the onset the service scheduled (its own sim time + delay): what /push_events carries
                    entry = dict(p, planned_start=p['start'], start=float(res.scheduled_start) if accepted else math.nan,
                                 delay=delay, requested_at_sim=now, accepted=accepted,
                                 id=int(res.push_id) if res else 0, message=res.message if res else 'no answer')
                    result['requested'].append(entry)
                    if accepted:
                        not_before = float(res.scheduled_end) + SEPARATION
                    if not entry['accepted']:
                        result['problems'].append(f'push {p} not accepted: {entry["message"]}')
                    next_push += 1
                if (now >= next_mem or (not final_sampled and now >= total - 1.0)):
                    pids = node_pids(launcher.pid)
                    sample = {'sim_time': now, 'wall': time.monotonic() - t0,
                              'rss_kb': {k: vm_rss_kb(v) for k, v in sorted(pids.items())}}
                    result['memory'].append(sample)
                    _log(f"sim {now:.1f} s / {total:.0f} s, wall {sample['wall']:.0f} s, "
                         f"pushes requested {next_push}/{len(plan)}, RSS kB {sample['rss_kb']}")
                    if now >= total - 1.0:
                        final_sampled = True
                    while next_mem <= now:
                        next_mem += mem_every
                time.sleep(0.2)
            result['launcher_exit_code'] = launcher.returncode
        except RuntimeError as exc:
            result['problems'].append(str(exc))
            if launcher.poll() is None:
                launcher.send_signal(signal.SIGINT)
            try:
                launcher.wait(120)
            except subprocess.TimeoutExpired:
                launcher.kill()
                launcher.wait()
            result['launcher_exit_code'] = launcher.returncode
        finally:
            for s, h in prev.items():
                signal.signal(s, h)
            node.destroy_node()
            rclpy.shutdown(context=ctx)
    result['wall_time'] = time.monotonic() - t0
    if result['launcher_exit_code'] != 0:
        result['problems'].append(f"launcher exited with {result['launcher_exit_code']}")
    # memory: minute 1 (or half the run) vs the end
    mem = result['memory']
    first = next((s for s in mem if s['sim_time'] >= mem_first_at), None)
    last = mem[-1] if mem else None
    growth = {}
    if first is None or last is None or last is first:
        result['problems'].append('memory: not enough samples')
    else:
        for name in NODE_NAMES:
            a, b = first['rss_kb'].get(name), last['rss_kb'].get(name)
            if a is None or b is None:
                result['problems'].append(f'memory: no sample of {name}')
                continue
            growth[name] = {'first_kb': a, 'last_kb': b, 'first_sim_time': first['sim_time'],
                            'last_sim_time': last['sim_time'], 'growth': (b - a) / a}
            if (b - a) / a >= MEMORY_GROWTH_LIMIT:
                result['problems'].append(f'memory: {name} grew {100 * (b - a) / a:.1f} % '
                                          f'({a} -> {b} kB)')
    result['memory_growth'] = growth
    try:
        accepted = [r for r in result['requested'] if r['accepted']]
        result['bag_check'] = analyze_bag(bag, accepted)
        result['problems'] += result['bag_check']['problems']
        if len(accepted) != len(plan):
            result['problems'].append(f'{len(accepted)} of {len(plan)} planned pushes accepted')
    except Exception as exc:  # noqa: BLE001 - report any reading problem plainly
        result['problems'].append(f'cannot check the bag: {exc!r}')
    result['ok'] = not result['problems']
    return result


def print_summary(r: dict) -> None:
    b = r.get('bag_check', {})
    print('==== soak summary ====')
    print(f"{r['minutes']} sim min, seed {r['seed']}, wall {r['wall_time']:.0f} s, launcher exit {r.get('launcher_exit_code')}")
    if b:
        print(f"messages {b['message_count']} ({b['mcap_bytes'] / 1e6:.1f} MB), states {b['states']}, sim time "
              f"{b['sim_time']:.3f} s, sequence gaps {b['sequence_gaps']}, repeats {b['sequence_repeats']}")
        print(f"pushes planned {len(r['plan'])}, accepted {sum(1 for x in r['requested'] if x['accepted'])}, "
              f"events {b['push_events']} ({b['forward_pushes']} forward, {b['backward_pushes']} backward), "
              f"impulse checked {b['pushes_checked']}, not checkable (impact in window) {b['pushes_not_checkable']}")
        print(f"survived: {b['survived']}; qp_status counts {b['qp_status_counts']}")
    for name, g in r.get('memory_growth', {}).items():
        print(f"RSS {name:11s} {g['first_kb']} kB at {g['first_sim_time']:.0f} s -> {g['last_kb']} kB at "
              f"{g['last_sim_time']:.0f} s ({100 * g['growth']:+.1f} %)")
    print('OK' if r['ok'] else 'PROBLEMS:\n  ' + '\n  '.join(r['problems']))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='soak', description='Soak run over DDS with pushes.')
    ap.add_argument('--minutes', type=float, default=10.0, help='simulated minutes')
    ap.add_argument('--json', type=Path, default=None)
    ap.add_argument('--bag', type=Path, default=None)
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--every', type=float, default=3.0, help='mean sim s between pushes')
    # [N] for the default robot, scaled for another by its M sqrt(g L) (robot_force_scale): within the
    # capability map's weakest boundaries for 0.025 s pushes in mode both (backward 193.75 N at
    # phase 0.25, forward 353 N at 0.85; docs/capability_map.md): a soak tests the software, not the robot
    ap.add_argument('--min-force', type=float, default=None, help='[N] (default 80, scaled for --robot)')
    ap.add_argument('--max-forward', type=float, default=None, help='[N] (default 150, scaled for --robot)')
    ap.add_argument('--max-backward', type=float, default=None, help='[N] (default 150, scaled for --robot)')
    ap.add_argument('--robot', default=None, metavar='NAME|PATH',
                    help='the robot the graph walks: a name under robots/ or a robot directory (default biped7; '
                         'docs/robots.md); the force defaults and the 250 N bound scale with its M sqrt(g L)')
    ap.add_argument('--timeout', type=float, default=None, help='wall s (default 600 + 30 per sim s)')
    ap.add_argument('--real-time-factor', type=float, default=1.0,
                    help="the simulator's pacing (1.0: sim time follows the wall clock, as a robot would; the "
                         "pushes are requested ~1 sim s ahead from /clock read every 0.2 s wall, so the graph "
                         "must not outrun the requests by much: keep it <= 2)")
    ap.add_argument('--lead', type=float, default=1.0, help='sim s before a planned onset at which it is requested')
    ap.add_argument('--min-lead', type=float, default=0.5,
                    help='smallest delay of a request [sim s] (when this process lags the graph)')
    a = ap.parse_args(argv)
    if not 0 < a.min_lead <= a.lead:
        ap.error('--min-lead must be in (0, --lead]')
    if not 0 < a.real_time_factor <= 2:
        ap.error('--real-time-factor must be in (0, 2]')
    if not a.minutes > 0:
        ap.error('--minutes must be > 0')
    try:
        k = robot_force_scale(a.robot)
    except ValueError as exc:      # RobotError / DescriptionError: one line naming the file or the field
        print(f'soak: error: {exc}', file=sys.stderr)
        return 2
    for name, default in (('min_force', 80.0), ('max_forward', 150.0), ('max_backward', 150.0)):
        if getattr(a, name) is None:
            setattr(a, name, default if k == 1.0 else round(default * k, 3))
    bound = 250.0 if k == 1.0 else round(250.0 * k, 3)
    for name in ('max_forward', 'max_backward'):
        if not 0 < getattr(a, name) <= bound:
            ap.error(f'--{name.replace("_", "-")} must be in (0, {bound:g}] N')
    from biped_model.settings import repo_root
    bag = (a.bag or repo_root() / 'runs' / f'soak_{_dt.datetime.now().strftime("%Y%m%d_%H%M%S")}').resolve()
    bag.parent.mkdir(parents=True, exist_ok=True)
    r = run_soak(a.minutes, bag, seed=a.seed, every=a.every, min_force=a.min_force, max_forward=a.max_forward,
                 max_backward=a.max_backward, lead=a.lead, min_lead=a.min_lead, timeout=a.timeout,
                 real_time_factor=a.real_time_factor, robot=a.robot)
    print_summary(r)
    if a.json:
        a.json.write_text(json.dumps(r, indent=2, default=float) + '\n')
        print(f'summary written to {a.json}')
    return 0 if r['ok'] else 1


if __name__ == '__main__':
    sys.exit(main())
