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
every 0.1 s with ``config/fastdds.xml``) for its reliable subscribers to acknowledge what it published
before it exits, and the recorder, once no publisher is left, takes everything still queued before it
finishes the bag (``--recorder-stop-timeout``, 30 s, between its SIGINT and SIGTERM).
It isolates nothing (children inherit ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE).

Waiting: the launcher sleeps until a child exits (one pidfd per child, readable once that process has
exited) or a signal arrives (``signal.set_wakeup_fd``), so a dead node is seen within milliseconds.

- A node that exits before the simulator finished (the simulator itself killed by a signal, or any other
  node exiting while the run goes on): "launch: node 'X' died unexpectedly (exit code N | killed by SIG...)",
  then every other node is stopped at once: SIGINT, SIGTERM ``--fault-stop-timeout`` s (0.5) later, SIGKILL
  as long again after that (this cuts short a survivor's wait for the acknowledgements of the dead node's
  readers: they stay matched after its death, and without the SIGTERM a survivor of a killed recorder
  lingered the whole 5 s of that wait), the recorder last and as at a normal end (it drains
  and finishes the bag). A killed recorder leaves its file without a summary: the launcher names the
  ``scripts/bag recover`` command that rewrites its complete chunks into a finished bag. Exit status 1, after
  "launch: graph stopped T s after node 'X' died".
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
import math
import os
import select
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


def describe_exit(code: int) -> str:
    """``exit code N`` for a process that exited, ``killed by SIGNAME`` for one a signal ended
    (``Popen.returncode`` -N)."""
    if code >= 0:
        return f'exit code {code}'
    try:
        return f'killed by {signal.Signals(-code).name}'
    except ValueError:
        return f'killed by signal {-code}'


class Child:
    """A node's process (own session, PR_SET_PDEATHSIG) and a pidfd on it (None where the kernel has no
    ``pidfd_open``): readable once the process has exited."""

    def __init__(self, name: str, cmd: list[str]):
        self.name = name
        self.cmd = cmd
        self.proc = subprocess.Popen(cmd, preexec_fn=_pdeathsig, start_new_session=True)
        try:
            self.pidfd: Optional[int] = os.pidfd_open(self.proc.pid)
        except (AttributeError, OSError):   # Python < 3.9 or Linux < 5.3: Waiter polls instead
            self.pidfd = None

    def poll(self) -> Optional[int]:
        return self.proc.poll()

    def signal(self, sig) -> None:
        if self.proc.poll() is None:
            try:
                self.proc.send_signal(sig)
            except ProcessLookupError:
                pass

    def close(self) -> None:
        if self.pidfd is not None:
            os.close(self.pidfd)
            self.pidfd = None


class Waiter:
    """Sleeps until a child exits or a signal with a Python handler arrives, at most a given time.

    Signals: ``signal.set_wakeup_fd`` on a non-blocking pipe (the C-level handler writes a byte, so the poll
    below wakes even though Python runs its handler only afterwards); restored by :meth:`close`. Must be
    created in the main thread. Children: their pidfds. A child without one makes every wait at most
    ``FALLBACK_POLL`` s."""

    FALLBACK_POLL = 0.05   # s

    def __init__(self):
        self._r, self._w = os.pipe()
        os.set_blocking(self._r, False)
        os.set_blocking(self._w, False)
        self._previous = signal.set_wakeup_fd(self._w)

    def wait(self, children, timeout: float) -> None:
        """Return once one of ``children`` has exited (at once if one already has), a signal arrived, or
        ``timeout`` s passed."""
        alive = [c for c in children if c.poll() is None]
        if len(alive) < len(children):
            return
        poller = select.poll()
        poller.register(self._r, select.POLLIN)
        for c in alive:
            if c.pidfd is not None:
                poller.register(c.pidfd, select.POLLIN)
            else:
                timeout = min(timeout, self.FALLBACK_POLL)
        poller.poll(max(0.0, timeout) * 1000.0)
        try:
            while os.read(self._r, 512):
                pass
        except BlockingIOError:
            pass

    def close(self) -> None:
        signal.set_wakeup_fd(self._previous)
        os.close(self._r)
        os.close(self._w)


def log(msg: str) -> None:
    print(f'launch: {msg}', file=sys.stderr, flush=True)


def stop_children(children: list[Child], timeout: float, waiter: Optional[Waiter] = None) -> None:
    """SIGINT, then SIGTERM after ``timeout`` s, then SIGKILL after ``timeout`` s more; waits for all.
    Without a ``waiter`` it polls every 20 ms."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        alive = [c for c in children if c.poll() is None]
        if not alive:
            break
        if sig != signal.SIGINT:
            log(f'{", ".join(c.name for c in alive)} still running: {sig.name}')
        for c in alive:
            c.signal(sig)
        deadline = time.monotonic() + timeout
        while True:
            alive = [c for c in alive if c.poll() is None]
            left = deadline - time.monotonic()
            if not alive or left <= 0:
                break
            if waiter is not None:
                waiter.wait(alive, left)
            else:
                time.sleep(min(left, 0.02))
    for c in children:
        c.proc.wait()


class NodeDied(RuntimeError):
    """A node of the graph exited while the launcher waited for the graph to come up."""

    def __init__(self, child: Child):
        self.child = child
        super().__init__(f"node '{child.name}' died unexpectedly ({describe_exit(child.poll())})")


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
                    raise NodeDied(c)
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
    from biped_model.settings import default_config_dir
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
    ap.add_argument('--fault-stop-timeout', type=float, default=0.5,
                    help='after a node died: s between SIGINT, SIGTERM and SIGKILL to the others (the recorder: '
                         'as at a normal stop)')
    ap.add_argument('--ready-file', type=Path, default=None, help='written once every node is started')
    ap.add_argument('--live', action='store_true',
                    help='start the Foxglove WebSocket bridge; simulator paced at real_time_factor 1.0')
    ap.add_argument('--port', type=int, default=None, help='--live: WebSocket port (default: the params file, 8765)')
    ap.add_argument('--robot', default=None, metavar='NAME|PATH',
                    help="the robot: a name under robots/ or a robot directory's path (default biped7): the "
                         "simulator's, controller's and disturbance node's parameter robot (docs/robots.md)")
    return ap.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    from biped_model.settings import repo_root
    params = (args.params or default_params()).resolve()
    if not params.is_file():
        log(f'no parameters file {params}')
        return 2
    bag = args.bag or repo_root() / 'runs' / f'run_{_dt.datetime.now().strftime("%Y%m%d_%H%M%S")}'
    bag = bag.resolve()
    if args.steps is not None and args.steps < 0:
        log('--steps must be >= 0')
        return 2
    for opt in ('start_timeout', 'stop_timeout', 'recorder_stop_timeout', 'fault_stop_timeout'):
        value = getattr(args, opt)
        if not (math.isfinite(value) and value >= 0):
            log(f'--{opt.replace("_", "-")} must be a finite number >= 0, got {value}')
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
    if args.robot is not None:      # checked here: one line naming the file, exit 2, before any node starts
        from biped_model.robot import RobotError, resolve_robot
        try:
            r = resolve_robot(args.robot)
            r.description()
            r.check_stamp()
        except RobotError as exc:
            log(str(exc))
            return 2
        for name in ('simulator', 'controller', 'disturbance'):
            extra.setdefault(name, [])
            extra[name] = ['-p', f'robot:={r.directory}'] + extra[name]
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
                    extra['disturbance'] = extra.get('disturbance', []) + ['-p', f'horizon:={float(value)}']
            except ValueError:
                pass   # the simulator itself rejects the bad value, naming it

    stop = {'signal': None}

    def on_signal(signum, _frame):
        if stop['signal'] is None:
            stop['signal'] = signum

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    waiter = Waiter()
    children: dict[str, Child] = {}
    status = 0
    dead: Optional[Child] = None   # the node whose exit ended the run
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
                    dead = sim
                else:
                    log(f'simulator finished (exit code {status}) after {time.monotonic() - t0:.2f} s')
                break
            bridge = children.get('bridge')
            if bridge is not None and not bridge_reported and bridge.poll() is not None:
                log(f"node 'bridge' died unexpectedly ({describe_exit(bridge.poll())}): "
                    'the run goes on without the live view')
                bridge_reported = True
            exited = [c for n, c in children.items() if n not in ('simulator', 'bridge') and c.poll() is not None]
            if exited:
                dead = exited[0]
                break
            waiter.wait([c for c in children.values() if c.poll() is None], 1.0)
    except NodeDied as exc:
        dead = exc.child
    except RuntimeError as exc:
        log(str(exc))
        status = 1
    finally:
        t_dead = time.monotonic()
        if dead is not None:
            log(f"node '{dead.name}' died unexpectedly ({describe_exit(dead.poll())}): stopping the graph")
            status = 1
        elif stop['signal'] is not None:
            log(f'got {signal.Signals(stop["signal"]).name}: stopping the graph')
            status = 128 + stop['signal']
        # simulator first, the recorder last
        order = [children[n] for n in ('simulator', 'controller', 'disturbance', 'bridge') if n in children]
        stop_children(order, args.fault_stop_timeout if dead is not None else args.stop_timeout, waiter)
        if 'recorder' in children:
            stop_children([children['recorder']], args.recorder_stop_timeout, waiter)
            rc = children['recorder'].poll()
            if rc not in (0, None) and status == 0:
                log(f'recorder exited with {rc}')
                status = 1
        if dead is not None:
            log(f"graph stopped {time.monotonic() - t_dead:.2f} s after node '{dead.name}' died")
            hint = unfinished_bag_hint(bag) if dead.name == 'recorder' else None
            if hint is not None:
                log(hint)
        for c in children.values():
            c.close()
        waiter.close()
        for s, h in previous.items():
            signal.signal(s, h)
    return status


MCAP_MAGIC = b'\x89MCAP0\r\n'   # the last 8 bytes of a finished MCAP file (after its footer)


def unfinished_bag_hint(bag: Path) -> Optional[str]:
    """For the bag of a recorder that died: None when its file is finished (ends with the MCAP magic after
    the footer), else the ``scripts/bag recover`` command that rewrites the file's complete chunks (the
    recorder writes a chunk out at least every ``chunk_time`` s) into a finished bag."""
    files = sorted(bag.glob('*.mcap')) if bag.is_dir() else []
    if not files:
        return f'the recorder left no bag file under {bag}'
    try:
        with open(files[0], 'rb') as fh:
            fh.seek(max(0, files[0].stat().st_size - len(MCAP_MAGIC)))
            if fh.read() == MCAP_MAGIC:
                return None
    except OSError as exc:
        return f'the bag file {files[0]} cannot be read: {exc}'
    return (f'the bag file {files[0]} is unfinished (no summary): scripts/bag recover {bag} {bag}_recovered '
            'rewrites its complete chunks into a finished bag')


if __name__ == '__main__':
    sys.exit(main())
