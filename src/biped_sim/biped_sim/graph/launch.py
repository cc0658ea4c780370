"""Launcher of the biped's node graph (ROS 2 ``launch`` is not on PyPI).

    python -m biped_sim.graph.launch [--params FILE] [--bag DIR] [--steps N] [--sim-param KEY:=VALUE ...]
                               [--live [--port N]]

Starts, as child processes (executables found as ``ros2 run`` finds them: ``<prefix>/lib/<pkg>/<exe>``
of the package's ament-index prefix), each with ``--ros-args --params-file FILE``:

1. ``recorder`` (``-p output_dir:=DIR``); the launcher waits until it is subscribed to every topic
   of the graph (checked over DDS by a small rclpy node of the launcher's own);
2. ``controller``, ``disturbance``, ``simulator`` (``--steps`` -> ``-p max_steps:=N``).

Then it waits for the simulator to finish and stops the others (SIGINT; SIGTERM after
``--stop-timeout`` s; SIGKILL after as long again), the recorder last so that it gets the last
messages: every node waits (at most 5 s: Fast DDS re-sends a lost sample after its next heartbeat,
every 3 s) for its reliable subscribers to acknowledge what it published before it exits, and the
recorder, once no publisher is left, takes everything still queued before it finishes the bag
(``--recorder-stop-timeout``, 30 s, between its SIGINT and SIGTERM).
It isolates nothing (children inherit ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE).

- A node that exits before the simulator finished: "launch: node 'X' died unexpectedly (exit code
  N)", every other node is stopped, exit status 1.
- SIGINT / SIGTERM to the launcher: forwarded (the simulator first, the recorder last), exit 130/143.
- Exit status otherwise: the simulator's (0 when the run ended by steps, time or fall).
- Children get PR_SET_PDEATHSIG(SIGTERM): they do not outlive a killed launcher.

``--ready-file FILE``: written (with the bag path) once every node is up, for scripts and tests.

``--live [--port N]``: also starts ``bridge`` (Foxglove WebSocket server, ``biped_sim.live.bridge_node``;
``-p port:=N`` when given, else the parameters file's, 8765) right after the recorder and waits until
it is subscribed to every topic, and sets the simulator's ``real_time_factor:=1.0`` (a later
``--sim-param real_time_factor:=...`` wins). The bridge is not part of the run: if it dies (or
cannot start, e.g. the port is in use) the launcher reports "node 'bridge' died unexpectedly (exit
code N): the run goes on without the live view" and carries on; its exit status stays the
simulator's. It is stopped after the disturbance node, before the recorder.
With the bridge's ``host_process: recorder`` (``config/graph.yaml``'s default) the bridge runs in the recorder's
process instead: ``live_recorder`` (``biped_sim.live.live_recorder``, the same ``recorder`` node plus the bridge
fed by its readers) takes the recorder's place and no ``bridge`` process is started; the launcher waits for
the recorder only (its readers are the bridge's), and a server that cannot start leaves the run recorded
without the live view (the recorder's log says so). ``own``: the separate ``bridge`` process above.
"""

from __future__ import annotations

import argparse
import ctypes
import datetime as _dt
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Optional

NODES = (  # (name, package, executable), in start order
    ('recorder', 'biped_sim', 'recorder'),
    ('controller', 'biped_controller', 'controller'),
    ('disturbance', 'biped_sim', 'disturbance'),
    ('simulator', 'biped_sim', 'simulator'),
)


def find_executable(package: str, executable: str) -> Path:
    """``<prefix>/lib/<package>/<executable>`` with the prefix from the ament index (as ``ros2 run``)."""
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix
    try:
        prefix = Path(get_package_prefix(package))
    except PackageNotFoundError as exc:
        raise FileNotFoundError(f'package {package!r} not found in the ament index '
                                f'(AMENT_PREFIX_PATH={os.environ.get("AMENT_PREFIX_PATH", "")})') from exc
    path = prefix / 'lib' / package / executable
    if not (path.is_file() and os.access(path, os.X_OK)):
        raise FileNotFoundError(f'no executable {executable!r} in {prefix / "lib" / package}')
    return path


def _pdeathsig():
    try:
        libc = ctypes.CDLL('libc.so.6', use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


class Child:
    def __init__(self, name: str, cmd: list[str]):
        self.name = name
        self.cmd = cmd
        self.proc = subprocess.Popen(cmd, preexec_fn=_pdeathsig, start_new_session=True)

    def poll(self) -> Optional[int]:
        return self.proc.poll()

    def signal(self, sig) -> None:
        if self.proc.poll() is None:
            try:
                self.proc.send_signal(sig)
            except ProcessLookupError:
                pass


def log(msg: str) -> None:
    print(f'launch: {msg}', file=sys.stderr, flush=True)


def stop_children(children: list[Child], timeout: float) -> None:
    """SIGINT, then SIGTERM after ``timeout``, then SIGKILL after ``timeout`` more; waits for all."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        alive = [c for c in children if c.poll() is None]
        if not alive:
            return
        if sig != signal.SIGINT:
            log(f'{", ".join(c.name for c in alive)} still running: {sig.name}')
        for c in alive:
            c.signal(sig)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and any(c.poll() is None for c in alive):
            time.sleep(0.02)
    for c in children:
        c.proc.wait()


BRIDGE = ('bridge', 'biped_sim', 'bridge')   # --live only, host_process own
LIVE_RECORDER = ('recorder', 'biped_sim', 'live_recorder')   # --live, host_process recorder: replaces the recorder
HOST_PROCESSES = ('recorder', 'own')   # bridge_node.HOST_PROCESSES (the launcher does not import the live room)


def wait_recorder_subscribed(timeout: float, watch: list[Child], stop: dict, node_name: str = 'recorder',
                             streams: bool = True) -> None:
    """Wait until the node ``node_name`` (the recorder; the bridge with --live) is subscribed to every
    topic of the graph (over DDS); ``streams`` False: every topic but the per-step streams
    (``graph_names.STREAM_QOS``), which the bridge subscribes to only while a client watches them."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from biped_sim.graph import names as gn
    ctx = rclpy.Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('launcher_probe', context=ctx, start_parameter_services=False)
    try:
        deadline = time.monotonic() + timeout
        while True:
            missing = [t for t, spec in gn.TOPICS.items() if (streams or spec.qos not in gn.STREAM_QOS)
                       and node_name not in {i.node_name for i in node.get_subscriptions_info_by_topic(t)}]
            if not missing:
                return
            for c in watch:
                if c.poll() is not None:
                    raise RuntimeError(f"node '{c.name}' died unexpectedly (exit code {c.poll()})")
            if stop['signal'] is not None:
                return
            if time.monotonic() > deadline:
                raise RuntimeError(f'the {node_name} is not subscribed after {timeout} s to {", ".join(missing)}')
            time.sleep(0.05)
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)


def bridge_reads_streams_on_demand(params: Path) -> bool:
    """The bridge's ``lazy_streams`` in the parameters file (false when absent or unreadable)."""
    import yaml
    try:
        tree = yaml.safe_load(params.read_text(encoding='utf-8')) or {}
        return bool(tree.get('bridge', {}).get('ros__parameters', {}).get('lazy_streams', False))
    except (OSError, yaml.YAMLError, AttributeError):
        return False


def bridge_host_process(params: Path) -> str:
    """The bridge's ``host_process`` in the parameters file (``recorder`` | ``own``; absent: ``recorder``, the
    default of config/graph.yaml). :raises ValueError: an unknown value (the message names the field)."""
    import yaml
    try:
        tree = yaml.safe_load(params.read_text(encoding='utf-8')) or {}
        value = tree.get('bridge', {}).get('ros__parameters', {}).get('host_process', 'recorder')
    except (OSError, yaml.YAMLError, AttributeError):
        value = 'recorder'
    if value not in HOST_PROCESSES:
        raise ValueError(f"bridge.host_process must be one of {', '.join(HOST_PROCESSES)}, got {value!r} ({params})")
    return value


def default_params() -> Path:
    from biped_sim.robot.settings import default_config_dir
    return default_config_dir() / 'graph.yaml'


def parse_args(argv=None):
    ap = argparse.ArgumentParser(prog='launch', description=__doc__.split('\n\n')[0])
    ap.add_argument('--params', type=Path, default=None, help='ROS parameters file (default config/graph.yaml)')
    ap.add_argument('--bag', type=Path, default=None, help='bag directory (default runs/run_<timestamp>)')
    ap.add_argument('--steps', type=int, default=None, help='simulator max_steps (walking steps)')
    ap.add_argument('--sim-param', action='append', default=[], metavar='KEY:=VALUE',
                    help='extra simulator parameter (repeatable)')
    ap.add_argument('--ctrl-param', action='append', default=[], metavar='KEY:=VALUE',
                    help='extra controller parameter (repeatable)')
    ap.add_argument('--stop-timeout', type=float, default=10.0, help='s between SIGINT, SIGTERM and SIGKILL')
    ap.add_argument('--recorder-stop-timeout', type=float, default=30.0,
                    help='s the recorder gets between SIGINT and SIGTERM (it drains its queues, then finishes the '
                         'bag: done as soon as they are empty; its own limit is 25 s)')
    ap.add_argument('--start-timeout', type=float, default=60.0, help='s to wait for the recorder')
    ap.add_argument('--grace', type=float, default=7.0,
                    help='s the survivors get after a node died (the simulator detects a dead controller)')
    ap.add_argument('--ready-file', type=Path, default=None, help='written once every node is started')
    ap.add_argument('--live', action='store_true',
                    help='start the Foxglove WebSocket bridge; simulator paced at real_time_factor 1.0')
    ap.add_argument('--port', type=int, default=None, help='--live: WebSocket port (default: the params file, 8765)')
    return ap.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    from biped_sim.robot.settings import repo_root
    params = (args.params or default_params()).resolve()
    if not params.is_file():
        log(f'no parameters file {params}')
        return 2
    bag = args.bag or repo_root() / 'runs' / f'run_{_dt.datetime.now().strftime("%Y%m%d_%H%M%S")}'
    bag = bag.resolve()
    if args.steps is not None and args.steps < 0:
        log('--steps must be >= 0')
        return 2
    if args.port is not None and not (args.live and 0 <= args.port <= 65535):
        log('--port needs --live and a port in [0, 65535]')
        return 2
    try:
        cohost = args.live and bridge_host_process(params) == 'recorder'
    except ValueError as exc:
        log(str(exc))
        return 2
    if cohost:
        nodes = (LIVE_RECORDER,) + NODES[1:]
    else:
        nodes = NODES[:1] + ((BRIDGE,) if args.live else ()) + NODES[1:]
    try:
        exes = {name: find_executable(pkg, exe) for name, pkg, exe in nodes}
    except FileNotFoundError as exc:
        log(str(exc))
        return 2
    extra = {'recorder': ['-p', f'output_dir:={bag}'],
             'simulator': [x for kv in args.sim_param for x in ('-p', kv)],
             'controller': [x for kv in args.ctrl_param for x in ('-p', kv)]}
    if args.steps is not None:
        extra['simulator'] += ['-p', f'max_steps:={args.steps}']
    if args.live:   # before the --sim-param values, which win
        extra['simulator'] = ['-p', 'real_time_factor:=1.0'] + extra['simulator']
        extra['bridge'] = ['-p', f'port:={args.port}'] if args.port is not None else []
        if cohost and args.port is not None:   # a process-wide -p: the recorder node does not declare `port`
            extra['recorder'] += extra['bridge']
    # a push that could only start after the run's end is refused by the service: the simulator's
    # max_time (when given) is the disturbance node's horizon
    for kv in args.sim_param:
        key, _, value = kv.partition(':=')
        if key.strip() == 'max_time':
            try:
                if float(value) > 0:
                    extra['disturbance'] = ['-p', f'horizon:={float(value)}']
            except ValueError:
                pass   # the simulator itself rejects the bad value, naming it

    stop = {'signal': None}

    def on_signal(signum, _frame):
        if stop['signal'] is None:
            stop['signal'] = signum

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    children: dict[str, Child] = {}
    status = 0
    bridge_reported = False   # a dead bridge is reported once and does not stop the run
    t0 = time.monotonic()
    try:
        for name, _pkg, _exe in nodes:
            if stop['signal'] is not None:
                break
            cmd = [str(exes[name]), '--ros-args', '--params-file', str(params), *extra.get(name, [])]
            children[name] = Child(name, cmd)
            if name == 'recorder':
                wait_recorder_subscribed(args.start_timeout, [children['recorder']], stop)
                log(f'recorder subscribed; bag {bag}' + (' (the live bridge in its process)' if cohost else ''))
            elif name == 'bridge':
                try:
                    wait_recorder_subscribed(args.start_timeout, [children['bridge']], stop, node_name='bridge',
                                             streams=not bridge_reads_streams_on_demand(params))
                    log('bridge subscribed (Foxglove WebSocket)')
                    # the simulator starts once it sees the bridge too (its readers then count among the
                    # subscribers that must be matched before the first state)
                    extra['simulator'] = ['-p', 'wait_for_bridge:=true'] + extra['simulator']
                except RuntimeError as exc:
                    log(f'{exc}: the run goes on without the live view')
                    bridge_reported = True
        if args.ready_file is not None and stop['signal'] is None:
            args.ready_file.write_text(f'{bag}\n')
        log(f'graph up ({", ".join(children)}) in {time.monotonic() - t0:.2f} s')
        sim = children.get('simulator')
        while stop['signal'] is None:
            if sim is not None and sim.poll() is not None:
                status = sim.poll()
                if status < 0:
                    log(f"node 'simulator' died unexpectedly (killed by {signal.Signals(-status).name})")
                    status = 1
                    deadline = time.monotonic() + min(args.grace, 3.0)   # the controller reports the silence
                    while time.monotonic() < deadline and stop['signal'] is None:
                        time.sleep(0.05)
                else:
                    log(f'simulator finished (exit code {status}) after {time.monotonic() - t0:.2f} s')
                break
            bridge = children.get('bridge')
            if bridge is not None and not bridge_reported and bridge.poll() is not None:
                log(f"node 'bridge' died unexpectedly (exit code {bridge.poll()}): the run goes on without the live view")
                bridge_reported = True
            dead = [c for n, c in children.items() if n not in ('simulator', 'bridge') and c.poll() is not None]
            if dead:
                c = dead[0]
                log(f"node '{c.name}' died unexpectedly (exit code {c.poll()})")
                status = 1
                # let the survivors notice (the simulator's command timeout ends its run with a final
                # state and /fall) before stopping them
                deadline = time.monotonic() + args.grace
                while sim is not None and sim.poll() is None and time.monotonic() < deadline \
                        and stop['signal'] is None:
                    time.sleep(0.05)
                break
            time.sleep(0.05)
    except RuntimeError as exc:
        log(str(exc))
        status = 1
    finally:
        if stop['signal'] is not None:
            log(f'got {signal.Signals(stop["signal"]).name}: stopping the graph')
            status = 128 + stop['signal']
        # simulator first, the recorder last
        order = [children[n] for n in ('simulator', 'controller', 'disturbance', 'bridge') if n in children]
        stop_children(order, args.stop_timeout)
        if 'recorder' in children:
            stop_children([children['recorder']], args.recorder_stop_timeout)
            rc = children['recorder'].poll()
            if rc not in (0, None) and status == 0:
                log(f'recorder exited with {rc}')
                status = 1
        for s, h in previous.items():
            signal.signal(s, h)
    return status


if __name__ == '__main__':
    sys.exit(main())
