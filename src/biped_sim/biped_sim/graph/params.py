"""Declared-parameter helpers shared by the biped's ROS 2 nodes (ROS layer).

Every parameter is declared with ``dynamic_typing`` so that a wrong type in a parameters file never
raises inside rclpy with an unrelated message: the ``get_*`` readers read each value back, check its
type and range and raise :class:`ParameterError` naming the parameter. Nodes catch it in ``main()``,
log it and exit with status 2 before anything is published.

Defaults: a node parameter's default is its value in ``config/graph.yaml`` (the node's
``ros__parameters``; each with its reason there), read by :func:`graph_default` when a ``get_*`` is
called without one, so no value of that file is repeated in code. Settings that have their home in
``config/simulator.yaml`` / ``config/controller.yaml`` are passed explicitly from those files.
"""

from __future__ import annotations

import math
import sys
import signal
import time
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable, Sequence

import yaml

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node

from biped_model.finite import finite_number

EXIT_OK = 0
EXIT_BAD_PARAMETER = 2
SPIN_SLICE = 0.1    # s between two looks of run_node at its stop conditions (signal, node.done, context)
ACK_TIMEOUT = 5.0   # s a stopping node waits for its reliable subscribers' acknowledgements: longer than Fast DDS's
                    # heartbeat period (3 s), the wait of a sample lost on the way (re-sent after the next heartbeat)
                    # (the launcher gives 10 s from SIGINT to SIGTERM)


class ParameterError(ValueError):
    """A node parameter has an invalid value; ``name`` says which one."""

    def __init__(self, name: str, message: str) -> None:
        super().__init__(f"invalid parameter '{name}': {message}")
        self.name = name


class GraphDefaultsError(LookupError):
    """config/graph.yaml has no default for a parameter a node reads (a programming error: the message
    names the node, the parameter and the file)."""


@lru_cache(maxsize=4)
def _graph_tree(path: str) -> dict:
    with open(path, encoding="utf-8") as fh:
        tree = yaml.safe_load(fh) or {}
    if not isinstance(tree, dict):
        raise GraphDefaultsError(f"{path}: expected <node>: {{ros__parameters: {{...}}}}")
    return tree


def graph_default(node_name: str, name: str, path: str | Path | None = None) -> Any:
    """The default of parameter ``name`` of node ``node_name``: its value in ``config/graph.yaml``."""
    if path is None:
        from biped_model.settings import default_config_dir
        path = default_config_dir() / "graph.yaml"
    params = (_graph_tree(str(path)).get(node_name) or {}).get("ros__parameters") or {}
    if name not in params:
        raise GraphDefaultsError(f"{path}: node '{node_name}' has no default for parameter '{name}'")
    return params[name]


def _default(node: Node, name: str, default: Any) -> Any:
    return graph_default(node.get_name(), name) if default is None else default


def _declare(node: Node, name: str, default: Any):
    desc = ParameterDescriptor(name=name, dynamic_typing=True)
    try:
        return node.declare_parameter(name, default, desc).value
    except Exception as exc:  # rclpy raises its own exception types for malformed overrides
        raise ParameterError(name, str(exc)) from exc


def get_float(node: Node, name: str, default: float | None = None, *, lo: float | None = None, hi: float | None = None,
              lo_open: bool = False, allow_nan: bool = False) -> float:
    v = _declare(node, name, float(_default(node, name, default)))
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ParameterError(name, f"expected a number, got {v!r}")
    v = float(v)
    if math.isnan(v) and allow_nan:
        return v
    finite_number(v, name, error=lambda m: ParameterError(name, m), message=f"must be finite, got {v}")
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise ParameterError(name, f"must be {'>' if lo_open else '>='} {lo}, got {v}")
    if hi is not None and v > hi:
        raise ParameterError(name, f"must be <= {hi}, got {v}")
    return v


def get_int(node: Node, name: str, default: int | None = None, *, lo: int | None = None, hi: int | None = None) -> int:
    v = _declare(node, name, int(_default(node, name, default)))
    if isinstance(v, bool) or not isinstance(v, int):
        raise ParameterError(name, f"expected an integer, got {v!r}")
    if lo is not None and v < lo:
        raise ParameterError(name, f"must be >= {lo}, got {v}")
    if hi is not None and v > hi:
        raise ParameterError(name, f"must be <= {hi}, got {v}")
    return int(v)


def get_bool(node: Node, name: str, default: bool | None = None) -> bool:
    v = _declare(node, name, bool(_default(node, name, default)))
    if not isinstance(v, bool):
        raise ParameterError(name, f"expected true or false, got {v!r}")
    return v


def get_str(node: Node, name: str, default: str | None = None, *, choices: Sequence[str] | None = None) -> str:
    v = _declare(node, name, str(_default(node, name, default)))
    if not isinstance(v, str):
        raise ParameterError(name, f"expected a string, got {v!r}")
    if choices is not None and v not in choices:
        raise ParameterError(name, f"must be one of {' | '.join(choices)}, got {v!r}")
    return v


def get_profile(node: Node):
    """The named profile of parameter ``profile`` (``config/profiles/NAME.yaml``,
    :mod:`biped_model.profiles`; default ``config/graph.yaml``); an unknown name or a malformed file
    raises ParameterError naming ``profile`` and the known profiles."""
    from biped_model.profiles import ProfileError, load_profile
    # declared once (the simulator reads it for its settings and for its perturbation)
    name = node.get_parameter('profile').value if node.has_parameter('profile') else get_str(node, 'profile')
    try:
        return load_profile(name)
    except ProfileError as exc:
        raise ParameterError('profile', str(exc)) from exc


def get_robot_name(node: Node) -> str:
    """The parameter ``robot`` (a name under robots/ or a path; '' the default robot), declared once."""
    return node.get_parameter('robot').value if node.has_parameter('robot') else get_str(node, 'robot')


def robot_settings(node: Node) -> tuple[tuple[str, object], ...]:
    """The robot's own settings (robots/<name>/settings.yaml, ``biped_model.robot.Robot.settings``: its
    size-dependent controller and simulator values; none for the default robot); a bad robot or file raises
    ParameterError naming ``robot``."""
    from biped_model.robot import RobotError, resolve_robot
    try:
        return resolve_robot(get_robot_name(node) or None).settings()
    except RobotError as exc:
        raise ParameterError('robot', str(exc)) from exc


def _declare_untyped(node: Node, name: str):
    """The value of parameter ``name`` declared with dynamic typing and no default (None when not given): an
    empty list in YAML or on the command line has no type, so a typed declaration would refuse it."""
    desc = ParameterDescriptor(name=name, dynamic_typing=True)
    try:
        return node.declare_parameter(name, None, desc).value
    except Exception as exc:
        raise ParameterError(name, str(exc)) from exc


def get_float_list(node: Node, name: str) -> list[float]:
    """A list of numbers (default: empty). An empty list in YAML has no type: accepted too."""
    v = _declare_untyped(node, name)
    if v is None:
        return []
    if isinstance(v, (str, bytes, bool)) or not hasattr(v, '__iter__'):
        raise ParameterError(name, f"expected a list of numbers, got {v!r}")
    out = []
    for x in v:
        if isinstance(x, bool) or not isinstance(x, (int, float)):
            raise ParameterError(name, f"expected a list of numbers, got element {x!r}")
        out.append(float(x))
    return out


def get_str_list(node: Node, name: str, default: Sequence[str] | None = None) -> list[str]:
    """A list of strings (default ``config/graph.yaml``'s). An empty list in YAML or on the command line has no
    type: accepted as empty; one string (``-p NAME:=key=value``) is a list of one."""
    v = _declare_untyped(node, name)
    if v is None:
        v = _default(node, name, default)
    if isinstance(v, str):
        return [v]
    if isinstance(v, (bytes, bool)) or not hasattr(v, '__iter__'):
        raise ParameterError(name, f"expected a list of strings, got {v!r}")
    out = []
    for x in v:
        if not isinstance(x, str):
            raise ParameterError(name, f"expected a list of strings, got element {x!r}")
        out.append(x)
    return out


def load_robot_files(node: Node):
    """(description, gait family) from the parameters ``robot`` (a name under robots/ or a path; empty = the
    default robot, robots/biped7), ``description_path`` and ``gait_family_path`` (empty = the robot's),
    checked against each other."""
    from biped_sim.graph.checks import RobotFilesError, load_robot_files as _load
    robot = get_robot_name(node)
    desc_path = get_str(node, 'description_path')
    fam_path = get_str(node, 'gait_family_path')
    try:
        return _load(desc_path, fam_path, robot)
    except RobotFilesError as exc:
        raise ParameterError(exc.field, str(exc)) from exc


def install_stop_handlers(callback: Callable[[int], None]) -> dict:
    """SIGINT and SIGTERM call ``callback(signum)``; returns the previous handlers."""
    previous = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        previous[sig] = signal.signal(sig, lambda signum, _frame: callback(signum))
    return previous


def restore_handlers(previous: dict) -> None:
    for sig, handler in previous.items():
        signal.signal(sig, handler)


EXECUTORS = ('events', 'single_threaded')


def make_executor(node: Node):
    """The executor named by the node's ``executor`` parameter (declared by ``declare_executor``):
    'events' = rclpy's C++ EventsExecutor (rclpy.experimental; callbacks dispatched from its own event
    queue instead of rebuilding a wait set for every spin), 'single_threaded' = rclpy's
    SingleThreadedExecutor. A node without the parameter gets the SingleThreadedExecutor."""
    from rclpy.executors import SingleThreadedExecutor
    kind = node.get_parameter('executor').value if node.has_parameter('executor') else 'single_threaded'
    if kind == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=node.context)
    return SingleThreadedExecutor(context=node.context)


def wait_all_acked(node: Node, timeout: float) -> list[str]:
    """Block until every reliable subscriber has acknowledged everything this node published (at most
    ``timeout`` s in all). A lockstep run ends faster than DDS repairs a lost sample (a reliable gap is
    re-sent at the writer's next heartbeat): leaving before the acknowledgements can cut the tail of a
    recording. Returns the topics still unacknowledged."""
    from rclpy.duration import Duration
    deadline = time.monotonic() + timeout
    late = []
    for pub in list(node.publishers):
        left = max(0.0, deadline - time.monotonic())
        if not pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))):
            late.append(pub.topic_name)
    return late


def declare_executor(node: Node) -> str:
    """Declare the ``executor`` parameter (one of EXECUTORS; default from config/graph.yaml); a bad value
    raises ParameterError naming it."""
    v = _declare(node, 'executor', _default(node, 'executor', None))
    if v not in EXECUTORS:
        raise ParameterError('executor', f"must be one of {', '.join(EXECUTORS)}, got {v!r}")
    return v


def _spinner(executor) -> Callable[[], None]:
    """One slice of spinning for ``run_node``'s loop. rclpy's SingleThreadedExecutor: ``spin_once`` (one callback,
    at most SPIN_SLICE s of waiting). The EventsExecutor: every event for SPIN_SLICE s, through its
    ``spin_until_future_complete`` on a future that never completes (this rclpy's ``spin`` takes no timeout):
    its ``spin_once`` returns after each callback, and the loop's own checks around it (``rclpy.ok``: the
    context's lock) took 15-20 % of the bridge's thread at 10 messages per millisecond (py-spy).
    A signal or ``node.done`` is then seen within SPIN_SLICE s."""
    from rclpy.executors import SingleThreadedExecutor
    if isinstance(executor, SingleThreadedExecutor):
        return lambda: executor.spin_once(timeout_sec=SPIN_SLICE)
    from rclpy.task import Future
    never = Future()
    return lambda: executor.spin_until_future_complete(never, timeout_sec=SPIN_SLICE)


def run_node(name: str, factory: Callable[[], Node], args=None, *, startup_errors: tuple = ()) -> int:
    """The ``main()`` of every node: init rclpy without its signal handlers, build the node (a
    ``ParameterError`` or one of ``startup_errors`` -> a message on stderr and exit code
    EXIT_BAD_PARAMETER, nothing half-started), spin until SIGINT/SIGTERM, external shutdown, or the node
    sets ``node.done``; then ``node.after_spin(executor, signum)`` if the node has one (a recorder
    drains and finishes its bag, the simulator reports why it stopped) gives the exit code (default 0);
    then at most ACK_TIMEOUT s for every reliable subscriber to acknowledge what the node published
    (:func:`wait_all_acked`). Cleans up in every case. A node may bring ``companions`` (nodes of the same
    process: added to the same executor, destroyed with it) and its own ``spinner(executor)`` (a callable for
    one slice of spinning; called once, after the stop handlers are installed)."""
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    node: Node | None = None
    try:
        try:
            node = factory()
        except (ParameterError, *startup_errors) as exc:
            print(f'{name}: {exc}', file=sys.stderr)
            return EXIT_BAD_PARAMETER
        stop = {'signal': None}
        previous = install_stop_handlers(lambda s: stop.__setitem__('signal', s))
        executor = make_executor(node)
        executor.add_node(node)
        for companion in getattr(node, 'companions', ()):   # nodes hosted in the same process (one executor)
            executor.add_node(companion)
        spinner = getattr(node, 'spinner', None)   # a node's own slice of spinning (the recorder's wait set)
        spin = spinner(executor) if spinner is not None else _spinner(executor)
        try:
            while stop['signal'] is None and not getattr(node, 'done', False) and rclpy.ok(context=node.context):
                spin()
        except (ExternalShutdownException, KeyboardInterrupt):
            pass
        finally:
            restore_handlers(previous)
        after = getattr(node, 'after_spin', None)
        code = after(executor, stop['signal']) if after is not None else 0
        # whatever the reason of the stop: the node's last messages reach the recorder before the process
        # (and the DDS writer history holding what a lagging reader has not acknowledged) is gone
        late = wait_all_acked(node, ACK_TIMEOUT)
        if late:
            node.get_logger().warning(f'not acknowledged within {ACK_TIMEOUT} s: {", ".join(late)}')
        return EXIT_OK if code is None else int(code)
    finally:
        if node is not None:
            for companion in getattr(node, 'companions', ()):
                companion.destroy_node()
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
