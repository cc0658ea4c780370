"""The controller interface: what any planar-biped controller receives and returns each control period.

Pure Python + NumPy, no ROS. A controller is a class built from a :class:`ControllerSetup` and driven by
the closed loop (``plugin.loop``) in three calls:

* ``reset(t, stance)``: a run starts at time ``t`` [s] with ``stance`` (``LEFT`` = 0 / ``RIGHT`` = 1) on the
  ground, the robot at the gait family's initial state;
* ``on_touchdown(t, stance)``: the sensed stance changed to ``stance`` at the period starting at ``t`` [s]
  (called before that period's ``compute``; the measured q, q' are already in the new stance's order);
* ``compute(obs) -> ControlResult``: one control period; the six torques are held over
  [obs.t, obs.t + period) (or until a touchdown ends the period early).

What a controller may not do: read the plant. It gets no handle on the simulator, the MuJoCo model or
the true state; everything it knows is in :class:`Observation` (the sensor model's output, exactly what
the plant's sensors report) and in its :class:`ControllerSetup` (the robot as given, which under a
perturbed plant is not the simulated one). The observation's arrays are read-only copies.

Units and frames (DESIGN.md): paper joint coordinates q1..q6 of the current stance (stance ankle,
stance knee, stance hip, swing hip, swing knee, swing ankle) [rad], rates [rad/s], torques [N m] in
the same order, times [s] of simulated time.

:func:`check_controller_class` tells whether a class satisfies the interface (an
:class:`InterfaceError` naming the class and the missing or malformed member otherwise);
:class:`GuardedController` wraps an instance and turns a non-finite or wrongly shaped torque, or a
malformed status, into a :class:`ControllerFault` naming the controller.
"""
from __future__ import annotations

import functools
import inspect
import math
from dataclasses import dataclass, field
from typing import Mapping, Protocol, Union, runtime_checkable

import numpy as np

from biped_model.description import RobotDescription
from biped_model.gait_family import GaitFamily

from biped_controller.plugin.model import Gains, Reference, RobotModel

N_JOINTS = 6

#: a status value the studies record: a plain number or flag
StatusValue = Union[float, int, bool]


@dataclass(frozen=True)
class ControllerSetup:
    """What a controller is built with (once per closed loop).

    ``desc``: the robot as the controller knows it (the nominal description; a perturbed plant differs
    from it); ``family``: the gait family q_d(p, tau) (stride p [m] in [p_min, p_max], phase tau [s] in
    [0, T]); ``period``: the control period [s]; ``options``: controller-specific settings (name -> value,
    empty by default), as given to :func:`biped_controller.plugin.registry.load_controller`.

    What a controller needs of the robot comes with it, from this package alone (``plugin.model``):
    :attr:`model` the fixed-stance-foot model of ``desc`` (dynamics A, H and the reaction rows, the centre
    of mass and its terms), :attr:`gains` the built-in computed-torque law's joint gains (``Kp``, ``Kv``),
    :attr:`reference` the gait family with named partial derivatives (q, dq/dp, dq/dtau, d2q/dtau2, ...)
    and the reference motion of eq. (11). ``model`` and ``reference`` are built on first use."""

    desc: RobotDescription
    family: GaitFamily
    period: float
    options: Mapping[str, object] = field(default_factory=dict)

    @functools.cached_property
    def model(self) -> RobotModel:
        """The controller-side model of :attr:`desc` (:class:`~biped_controller.plugin.model.RobotModel`)."""
        return RobotModel(self.desc)

    @functools.cached_property
    def gains(self) -> Gains:
        """The joint PD gains ``Kp`` [1/s^2], ``Kv`` [1/s] of ``config/controller.yaml``
        (:class:`~biped_controller.plugin.model.Gains`)."""
        return Gains.from_config()

    @functools.cached_property
    def reference(self) -> Reference:
        """The gait family as a controller reads it (:class:`~biped_controller.plugin.model.Reference`)."""
        return Reference(self.family)


def stamp_time(t: float) -> float:
    """Sim time ``t`` [s] as a ROS stamp carries it: rounded to the nanosecond (``biped_sim.graph.cdr.stamp_parts``)
    and read back as sec + 1e-9 nanosec, the controller node's time of a state. The in-process loop gives
    the controller this time too, so a controller sees the same ``t`` in process and over DDS."""
    ns = int(round(t * 1e9))
    sec, nsec = divmod(ns, 1_000_000_000)
    return sec + 1e-9 * nsec


@dataclass(frozen=True, eq=False)
class Observation:
    """What a controller receives at the start of a control period.

    * ``t`` [s]: the period's start (simulated time rounded to the nanosecond, :func:`stamp_time`; a
      period that follows a touchdown starts at the touchdown instant, off the control grid);
    * ``step``: index of the period since the run's start;
    * ``stance``: the sensed stance foot (0 = LEFT, 1 = RIGHT);
    * ``q`` (6,) [rad], ``qd`` (6,) [rad/s]: the sensed joint state in paper coordinates of ``stance``
      (the plant's sensor model applied: noise, quantisation, delay; the true state with ideal sensors);
    * ``pitch`` [rad], ``pitch_rate`` [rad/s]: the IMU's torso pitch in the world (counter-clockwise
      positive) and its gyro rate; NaN when the plant gives no IMU reading;
    * ``last_torque`` (6,) [N m]: the torque the plant applied over the previous period (after its torque
      limits), in paper order of ``last_stance`` (zeros before the first period);
    * ``last_stance``: the stance of the previous period (``stance`` before the first period); it differs
      from ``stance`` in the first period after a touchdown.
    """

    t: float
    step: int
    stance: int
    q: np.ndarray
    qd: np.ndarray
    pitch: float = math.nan
    pitch_rate: float = math.nan
    last_torque: np.ndarray = field(default_factory=lambda: np.zeros(N_JOINTS))
    last_stance: int = -1

    @staticmethod
    def frozen(t: float, step: int, stance: int, q: np.ndarray, qd: np.ndarray, pitch: float, pitch_rate: float,
               last_torque: np.ndarray, last_stance: int) -> "Observation":
        """An observation holding read-only copies of the arrays (what the loop hands a controller)."""
        arrs = []
        for a in (q, qd, last_torque):
            c = np.array(a, dtype=float)
            c.setflags(write=False)
            arrs.append(c)
        return Observation(float(t), int(step), int(stance), arrs[0], arrs[1], float(pitch), float(pitch_rate),
                           arrs[2], int(last_stance))


@dataclass(frozen=True, eq=False)
class ControlResult:
    """What a controller returns for one period: ``torque`` (6,) [N m] in paper order of the observation's
    stance, and ``status``: name -> number or flag (recorded per period by the studies and the bag;
    a key the studies read: ``p`` [m] and ``tau_dot`` [-] when the controller has a stride and a time
    scaling, for the survival criterion's return to the preferred gait). ``record`` (optional, None by
    default): the controller's own typed record of the period, passed on unchecked beside the status; the
    built-in modes give their ``ControllerStatusData``, which the controller node publishes whole."""

    torque: np.ndarray
    status: Mapping[str, StatusValue] = field(default_factory=dict)
    record: object = None


@runtime_checkable
class Controller(Protocol):
    """The interface (module docstring). A class satisfying it is built as ``cls(setup)``."""

    def reset(self, t: float, stance: int) -> None: ...

    def on_touchdown(self, t: float, stance: int) -> None: ...

    def compute(self, obs: Observation) -> ControlResult: ...


class InterfaceError(TypeError):
    """A class does not satisfy :class:`Controller` (the message names the class and the member)."""


class ControllerFault(RuntimeError):
    """A controller returned something the plant cannot apply: a non-finite torque, a torque of the wrong
    shape, a malformed status, or it raised an exception in ``reset``, ``on_touchdown`` or ``compute``
    (the message names the controller, the period and the fault).
    ``controller`` the controller's name, ``t`` [s] the period, ``kind`` one of :data:`FAULT_KINDS`."""

    def __init__(self, controller: str, t: float, kind: str, detail: str):
        super().__init__(f"controller {controller!r} at t = {t:.6f} s: {kind}: {detail}")
        self.controller, self.t, self.kind, self.detail = controller, t, kind, detail


FAULT_KINDS = ("wrong result type", "wrong torque shape", "non-finite torque", "malformed status", "raised")

#: method -> the positional parameters it takes after ``self``: the time first, then what it is about (as in
#: ``Observation(t, step, stance, ...)``); ``reset`` took (stance, t) before the order was made one
_METHODS = {"reset": ("t", "stance"), "on_touchdown": ("t", "stance"), "compute": ("obs",)}


def _describe(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def _check_order(name: str, meth: str, params: tuple[str, ...], sig: inspect.Signature) -> None:
    """An :class:`InterfaceError` when ``meth``'s first positional parameters after ``self`` carry the
    interface's names in another order (e.g. ``reset(self, stance, t)``, the order before both methods took
    the time first): the loop passes them by position, so the swapped names would silently swap values."""
    pos = [p.name for p in sig.parameters.values()
           if p.kind in (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)][1:1 + len(params)]
    if len(pos) == len(params) and list(pos) != list(params) and sorted(pos) == sorted(params):
        raise InterfaceError(f"controller class {name}: {meth} takes ({', '.join(params)}) in that order, its "
                             f"signature is {meth}{sig} (the time comes first in every call)")


def check_controller_class(cls: object) -> type:
    """``cls`` itself when it is a class whose instances satisfy :class:`Controller`: callable ``reset``,
    ``on_touchdown`` and ``compute`` that accept the interface's positional arguments, and a constructor
    that accepts one (the :class:`ControllerSetup`). Raises :class:`InterfaceError` naming the class and
    the first member that is missing or takes the wrong arguments (also when a method names the
    interface's parameters in another order: :func:`_check_order`)."""
    if not inspect.isclass(cls):
        raise InterfaceError(f"{cls!r} is not a class (a controller is registered as a class built from a "
                             f"ControllerSetup)")
    name = _describe(cls)
    for meth, params in _METHODS.items():
        f = getattr(cls, meth, None)
        if f is None or not callable(f):
            raise InterfaceError(f"controller class {name} has no method {meth}({', '.join(params)}) "
                                 f"(biped_controller.plugin.interface.Controller)")
        try:
            sig = inspect.signature(f)
            sig.bind(None, *params)
        except TypeError as exc:
            raise InterfaceError(f"controller class {name}: {meth} must accept ({', '.join(params)}), "
                                 f"its signature is {meth}{inspect.signature(f)}: {exc}") from None
        except ValueError:          # a builtin without a signature: accepted as it is
            continue
        _check_order(name, meth, params, sig)
    try:
        inspect.signature(cls).bind("setup")
    except TypeError as exc:
        raise InterfaceError(f"controller class {name}: the constructor must accept one ControllerSetup, "
                             f"its signature is {cls.__name__}{inspect.signature(cls)}: {exc}") from None
    except ValueError:
        pass
    return cls


class GuardedController:
    """An interface controller whose every result is checked before the plant gets it: ``compute`` returns
    a :class:`ControlResult` whose torque is a float array of shape (6,) (a copy) with finite entries and
    whose status maps ``str`` to ``bool``, ``int`` or ``float`` (NumPy scalars converted); anything else
    raises :class:`ControllerFault` naming ``name``, as does an exception raised by the controller's
    ``reset``, ``on_touchdown`` or ``compute`` (kind ``raised``, the original chained)."""

    def __init__(self, inner: Controller, name: str):
        self.inner, self.name = inner, name

    def _call(self, what: str, t: float, f, *args):
        try:
            return f(*args)
        except ControllerFault:
            raise
        except Exception as exc:     # the controller's own code failed: a fault of this controller, not of the study
            raise ControllerFault(self.name, t, FAULT_KINDS[4], f"{what} raised {type(exc).__name__}: {exc}") from exc

    def reset(self, t: float, stance: int) -> None:
        self._call("reset", t, self.inner.reset, t, stance)

    def on_touchdown(self, t: float, stance: int) -> None:
        self._call("on_touchdown", t, self.inner.on_touchdown, t, stance)

    def compute(self, obs: Observation) -> ControlResult:
        out = self._call("compute", obs.t, self.inner.compute, obs)
        if not isinstance(out, ControlResult):
            raise ControllerFault(self.name, obs.t, FAULT_KINDS[0],
                                  f"compute returned {type(out).__name__}, not a ControlResult")
        try:
            torque = np.array(out.torque, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ControllerFault(self.name, obs.t, FAULT_KINDS[1], f"torque is not numeric: {exc}") from None
        if torque.shape != (N_JOINTS,):
            raise ControllerFault(self.name, obs.t, FAULT_KINDS[1],
                                  f"torque has shape {torque.shape}, expected ({N_JOINTS},)")
        if not np.all(np.isfinite(torque)):
            bad = ", ".join(str(int(i) + 1) for i in np.flatnonzero(~np.isfinite(torque)))   # plain numbers
            raise ControllerFault(self.name, obs.t, FAULT_KINDS[2], f"torque {torque.tolist()} (joints {bad})")
        return ControlResult(torque, self._status(out.status, obs.t), out.record)

    def _status(self, status: object, t: float) -> dict[str, StatusValue]:
        if not isinstance(status, Mapping):
            raise ControllerFault(self.name, t, FAULT_KINDS[3], f"status is {type(status).__name__}, not a mapping")
        clean: dict[str, StatusValue] = {}
        for k, v in status.items():
            tv = type(v)
            if (tv is float or tv is int or tv is bool) and type(k) is str:     # the common case, kept as it is
                clean[k] = v
                continue
            if not isinstance(k, str):
                raise ControllerFault(self.name, t, FAULT_KINDS[3], f"status key {k!r} is not a str")
            if isinstance(v, (bool, np.bool_)):
                clean[k] = bool(v)
            elif isinstance(v, (int, np.integer)):
                clean[k] = int(v)
            elif isinstance(v, (float, np.floating)):
                clean[k] = float(v)
            else:
                raise ControllerFault(self.name, t, FAULT_KINDS[3],
                                      f"status[{k!r}] = {v!r} is {type(v).__name__}, not a number or flag")
        return clean
