"""Policies as controllers: a network from the policy observation to the action, run behind the controller
interface (``plugin.interface``) exactly as the environment (``policy.env``) runs it.

:class:`PolicyController` holds the action over the policy period: at a decision (the run's first period,
a sensed stance change, or the first period at or after the next instant k * policy_period of the policy
grid) it builds the observation vector of ``policy.spec`` from the interface's observation and its own
count of the time in stance (``reset``, ``on_touchdown``), evaluates the network, and returns the torques
a * tau_max (a clipped to [-1, 1], a NaN kept: the loop's guard records it as the controller's fault); in
the periods between two decisions it returns the held torques. With ``action_mode`` ``"residual"``
(``policy.residual``) the decision holds the offset a * residual_scale [rad] instead, and every period's
torque is the computed-torque law on the offset reference at that period's observation. On the plug-in loop
it reproduces the environment's episode period by period (the test: tests/test_policy.py).

:class:`OnnxPolicy` (registered as ``onnx_policy``; option ``file``: the ``.onnx`` path, ``policy_period``:
[s], default the file's metadata or config/policy_env.yaml's) evaluates an ONNX file with onnxruntime
(one thread: a study runs one controller per process). Its one input takes the (22,) observation as
(1, 22) or (22,) float32 or float64, its first output gives the (6,) action as (1, 6) or (6,); a file whose
input or output does not match raises :class:`PolicyFileError` naming the file and the shape. A committed
policy (``policies/<name>/``: ``policy.onnx`` and ``policy.json``) is a controller by its name
(``policy.catalog``). A ``policy.json`` with ``"action_mode": "residual"`` makes it a residual policy, with
that file's ``residual_scale`` and ``gains`` (``Kp``, ``Kv``; default config/controller.yaml's).
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Callable

import numpy as np

from biped_controller.plugin.interface import ControllerSetup, ControlResult, Observation
from biped_controller.plugin.model import Gains
from biped_controller.policy.residual import ResidualLaw
from biped_controller.policy.spec import (ACTION_MODES, GRID_TOL, OBS_FIELDS, OBS_SIZE, action_fields,
                                          check_policy_period, decision_grid_end, observation_vector, torque_limits)


class PolicyFileError(ValueError):
    """A policy file cannot be used: missing, not ONNX, inputs or outputs of the wrong shape, metadata that
    does not match the environment's observation or action (the message names the file)."""


class PolicyController:
    """A network ``forward(obs (22,)) -> action (6,)`` held over ``policy_period`` [s] (module docstring).
    Subclasses give :meth:`forward` (or pass ``forward``)."""

    description = "a policy network, its action held over its policy period"

    def __init__(self, setup: ControllerSetup, forward: Callable[[np.ndarray], np.ndarray] | None = None,
                 policy_period: float | None = None, action_mode: str | None = None,
                 residual_scale=None, gains: Gains | None = None):
        self.setup = setup
        if forward is not None:
            self.forward = forward
        if policy_period is None:
            policy_period = setup.options.get("policy_period", None)
        if policy_period is None or action_mode is None or residual_scale is None:
            from biped_controller.policy.env import load_env_config
            env_cfg = load_env_config()
            policy_period = env_cfg.policy_period if policy_period is None else policy_period
            action_mode = env_cfg.action_mode if action_mode is None else action_mode
            residual_scale = env_cfg.residual_scale if residual_scale is None else residual_scale
        self.policy_period = check_policy_period(float(policy_period), setup.period)
        action_fields(action_mode)                     # ValueError naming an unknown mode
        self.action_mode = action_mode
        self.residual = (ResidualLaw(setup.desc, setup.family, residual_scale, gains)
                         if action_mode == "residual" else None)
        self.limits = torque_limits(setup.desc)
        self._vec = np.empty(OBS_SIZE)
        self.decisions = 0
        self.reset(0.0, 0)

    def forward(self, obs: np.ndarray) -> np.ndarray:    # pragma: no cover - replaced by a subclass or the argument
        raise NotImplementedError

    def reset(self, t: float, stance: int) -> None:
        self._t_stance = t
        self._next = -math.inf
        self._stance = None
        self._torque = np.zeros(6)
        self._delta = np.zeros(6)

    def on_touchdown(self, t: float, stance: int) -> None:
        self._t_stance = t

    def compute(self, obs: Observation) -> ControlResult:
        law = self.residual
        decide = obs.stance != self._stance or obs.t >= self._next - GRID_TOL
        if decide or law is not None:
            vec = observation_vector(obs.q, obs.qd, obs.pitch, obs.pitch_rate, obs.stance, obs.t - self._t_stance,
                                     obs.last_torque, self.limits, out=self._vec)
        if decide:
            a = np.asarray(self.forward(vec), dtype=float).reshape(-1)
            if a.shape != (6,):
                raise PolicyFileError(f"the policy returned {a.size} values, expected 6")
            if law is None:
                self._torque = np.clip(a, -1.0, 1.0) * self.limits      # NaN stays NaN: the guard's fault
            else:
                self._delta = law.offset(a)
            self._stance = obs.stance
            self._next = decision_grid_end(obs.t, self.policy_period)
            self.decisions += 1
        if law is not None:                  # the computed-torque law on the offset reference, every period
            self._torque = law.torque(vec, self._delta)
        return ControlResult(self._torque.copy(), {"policy_decisions": self.decisions})


def _shape_ok(shape, n: int) -> bool:
    """An ONNX tensor shape (ints, None or symbolic names) that can hold one vector of n: (n,) or (b, n),
    b 1 or free."""
    dims = list(shape or [])
    if len(dims) == 1:
        return dims[0] == n or not isinstance(dims[0], int)
    if len(dims) == 2:
        return (dims[0] == 1 or not isinstance(dims[0], int)) and (dims[1] == n or not isinstance(dims[1], int))
    return False


def check_metadata(meta: dict, where: str) -> dict:
    """``meta`` (a policy's ``policy.json``) when its ``observation`` and ``action`` lists, where given, are
    the environment's (``spec.OBS_FIELDS``, ``spec.ACTION_FIELDS``); :class:`PolicyFileError` otherwise."""
    if not isinstance(meta, dict):
        raise PolicyFileError(f"{where}: expected a JSON object")
    mode = meta.get("action_mode", "torque")
    if mode not in ACTION_MODES:
        raise PolicyFileError(f"{where}: action_mode must be one of {ACTION_MODES}, got {mode!r}")
    for key, want in (("observation", OBS_FIELDS), ("action", action_fields(mode))):
        if key in meta and list(meta[key]) != list(want):
            raise PolicyFileError(f"{where}: {key} lists {list(meta[key])}, this environment's is {list(want)} "
                                  f"(biped_controller.policy.spec, action_mode {mode})")
    if mode == "residual":
        rs = meta.get("residual_scale")
        try:
            ok = rs is not None and ResidualLaw.check_scale(rs) is not None
        except ValueError:
            ok = False
        if not ok:
            raise PolicyFileError(f"{where}: a residual policy needs residual_scale, a number > 0 [rad] or six, "
                                  f"got {rs!r}")
        g = meta.get("gains")
        if g is not None and not (isinstance(g, dict) and all(
                isinstance(g.get(k), (int, float)) and not isinstance(g.get(k), bool) and math.isfinite(g[k])
                and g[k] > 0 for k in ("Kp", "Kv"))):
            raise PolicyFileError(f"{where}: gains must be {{'Kp': > 0, 'Kv': > 0}}, got {g!r}")
    if "policy_period" in meta:
        p = meta["policy_period"]
        if isinstance(p, bool) or not isinstance(p, (int, float)) or not math.isfinite(p) or p <= 0:
            raise PolicyFileError(f"{where}: policy_period must be a number > 0 [s], got {p!r}")
    return meta


class OnnxRunner:
    """One ONNX file evaluated by onnxruntime on the CPU: ``runner(obs (22,)) -> action (6,)`` (float64).
    Raises :class:`PolicyFileError` naming the file when it is missing, not a model onnxruntime loads, or
    its first input / first output is not a (22,) / (6,) vector (a leading batch of 1 or free allowed)."""

    def __init__(self, path: str | Path):
        import onnxruntime as ort
        self.path = Path(path)
        if not self.path.is_file():
            raise PolicyFileError(f"policy file {self.path}: no such file")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(str(self.path), sess_options=opts, providers=["CPUExecutionProvider"])
        except Exception as exc:     # onnxruntime raises its own exception types for a bad file
            raise PolicyFileError(f"policy file {self.path}: onnxruntime cannot load it: "
                                  f"{type(exc).__name__}: {exc}") from None
        ins, outs = self.session.get_inputs(), self.session.get_outputs()
        if len(ins) != 1:
            raise PolicyFileError(f"policy file {self.path}: {len(ins)} inputs, expected one (the observation)")
        i, o = ins[0], outs[0]
        if not _shape_ok(i.shape, OBS_SIZE):
            raise PolicyFileError(f"policy file {self.path}: input {i.name!r} has shape {i.shape}, expected "
                                  f"({OBS_SIZE},) or (batch, {OBS_SIZE}) (the observation of policy.spec)")
        if not _shape_ok(o.shape, 6):
            raise PolicyFileError(f"policy file {self.path}: output {o.name!r} has shape {o.shape}, expected (6,) "
                                  f"or (batch, 6) (the action)")
        self.dtype = {"tensor(float)": np.float32, "tensor(double)": np.float64}.get(i.type)
        if self.dtype is None:
            raise PolicyFileError(f"policy file {self.path}: input {i.name!r} is {i.type}, expected float or double")
        self.input_name, self.output_name = i.name, o.name
        self._batched = len(i.shape) == 2
        self._x = np.empty((1, OBS_SIZE) if self._batched else (OBS_SIZE,), dtype=self.dtype)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        self._x.reshape(-1)[:] = obs
        out = self.session.run([self.output_name], {self.input_name: self._x})[0]
        a = np.asarray(out, dtype=float).reshape(-1)
        if a.shape != (6,):
            raise PolicyFileError(f"policy file {self.path}: output {self.output_name!r} gave {a.size} values, "
                                  f"expected 6")
        return a


def read_metadata(onnx_path: Path) -> dict:
    """The ``policy.json`` beside ``onnx_path`` (checked: :func:`check_metadata`), {} when there is none."""
    meta_path = onnx_path.with_name("policy.json")
    if not meta_path.is_file():
        return {}
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise PolicyFileError(f"{meta_path}: cannot be read as JSON: {exc}") from None
    return check_metadata(meta, str(meta_path))


def check_robot(meta: dict, setup: ControllerSetup, path: Path) -> None:
    """A policy trained on one robot (its ``policy.json``'s ``robot``, as ``biped_model.robot.robot_label``
    names it) is not run on another: :class:`PolicyFileError` naming both when the controller's description
    (``setup.desc.source``, its robot's directory) is another robot's. Nothing is checked when either is
    unknown (no ``robot`` in the file, a description built in code)."""
    want = meta.get("robot")
    src = getattr(setup.desc, "source", "")
    if not want or not src:
        return
    from biped_model.robot import robot_label
    have = robot_label(str(Path(src).resolve().parent))
    if have != want:
        raise PolicyFileError(f"{path}: trained on robot {want!r} (its policy.json), asked to run on robot {have!r}; "
                              f"train one for that robot (scripts/train --robot {have}) or run this one on {want!r}")


class OnnxPolicy(PolicyController):
    """An ONNX policy file run by onnxruntime, its action held over its policy period (options ``file``:
    the ``.onnx`` path; ``policy_period`` [s]: default the ``policy.json`` beside the file, else
    config/policy_env.yaml)."""

    description = "an ONNX policy (option file=PATH) held over its policy period (docs/policies.md)"
    #: the file a subclass is bound to (``policy.catalog``); None: the ``file`` option
    policy_file: str | None = None
    #: options a study must pass (``trial.args.controller_arg`` refuses the name otherwise); none when bound
    required_options: tuple[str, ...] = ("file",)

    def __init__(self, setup: ControllerSetup):
        path = self.policy_file if self.policy_file is not None else setup.options.get("file")
        if not path:
            raise PolicyFileError("onnx_policy: give the policy file as the option file=PATH")
        path = Path(str(path))
        meta = read_metadata(path)
        check_robot(meta, setup, path)
        period = setup.options.get("policy_period", meta.get("policy_period"))
        self.runner = OnnxRunner(path)
        self.metadata = meta
        mode = meta.get("action_mode", "torque")
        gains = Gains(Kp=float(meta["gains"]["Kp"]), Kv=float(meta["gains"]["Kv"])) if "gains" in meta else None
        super().__init__(setup, self.runner, policy_period=period, action_mode=mode,
                         residual_scale=meta.get("residual_scale", 1.0), gains=gains)

    def provenance(self) -> dict:
        """The policy's files for a run's record (``plugin.provenance``): the ONNX file's absolute path and
        SHA-256, the ``policy.json`` beside it (its SHA-256, when there is one) and the policy period [s]."""
        from biped_controller.plugin.provenance import file_sha256
        path = self.runner.path.resolve()
        out = {"policy_file": str(path), "policy_sha256": file_sha256(path), "policy_period": self.policy_period}
        meta = path.with_name("policy.json")
        if meta.is_file():
            out["policy_json_sha256"] = file_sha256(meta)
        return out
