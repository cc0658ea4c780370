"""Pushes as the environment takes them: ``reset(options={"push": {...}})`` validated here, and the random
pushes a training wrapper draws (``policy.env.RandomPushes``).

A push option is a mapping (or a list of them) with

* ``force`` [N]: its magnitude, finite and >= 0 (a signed force is accepted when ``direction`` is absent:
  + forward);
* ``onset`` [s]: its start in simulated time since the reset, finite and >= 0 (the reset is t = 0: an onset
  below it is in the past);
* ``duration`` [s]: finite and > 0;
* ``direction``: ``"forward"`` (on the back, + world x, the default) or ``"backward"``;
* ``height`` [m] (optional): the point on the torso above the hip (default: the simulator's
  ``push_height``).

:func:`parse_push_option` returns the pushes (``biped_sim.plant.push.Push``, force signed) or raises
:class:`PushOptionError` naming the field; it changes nothing.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from biped_sim.plant.push import Push

DIRECTIONS = ("forward", "backward")
_KEYS = ("force", "onset", "duration", "direction", "height")


class PushOptionError(ValueError):
    """A push option is malformed or out of range; ``field`` names the field."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field

    def __reduce__(self):
        # pickled with its field (a vector environment's worker sends it to the main process)
        return (type(self), (self.field, str(self)))


def _number(spec: Mapping, key: str, where: str) -> float:
    v = spec[key]
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise PushOptionError(key, f"{where}{key}: expected a number, got {v!r}")
    v = float(v)
    if not math.isfinite(v):
        raise PushOptionError(key, f"{where}{key}: must be finite, got {v!r}")
    return v


def parse_push_option(option: object) -> tuple[Push, ...]:
    """The pushes of ``options["push"]`` (module docstring); None or an empty list: none."""
    if option is None:
        return ()
    specs = [option] if isinstance(option, Mapping) else option
    if not isinstance(specs, Sequence) or isinstance(specs, (str, bytes)):
        raise PushOptionError("push", f"push: expected a mapping or a list of mappings, got {option!r}")
    out = []
    for i, spec in enumerate(specs):
        where = "push: " if len(specs) == 1 else f"push[{i}]: "
        if not isinstance(spec, Mapping):
            raise PushOptionError("push", f"{where}expected a mapping, got {spec!r}")
        unknown = [k for k in spec if k not in _KEYS]
        if unknown:
            raise PushOptionError(str(unknown[0]), f"{where}unknown field {unknown[0]!r}; fields: {', '.join(_KEYS)}")
        for k in ("force", "onset", "duration"):
            if k not in spec:
                raise PushOptionError(k, f"{where}{k} is missing (force [N], onset [s], duration [s])")
        force = _number(spec, "force", where)
        onset = _number(spec, "onset", where)
        duration = _number(spec, "duration", where)
        if duration <= 0:
            raise PushOptionError("duration", f"{where}duration must be > 0 s, got {duration!r}")
        if onset < 0:
            raise PushOptionError("onset", f"{where}onset {onset!r} s is in the past (the reset is t = 0 s)")
        sign = 1.0
        if "direction" in spec:
            d = spec["direction"]
            if d not in DIRECTIONS:
                raise PushOptionError("direction", f"{where}direction must be one of {DIRECTIONS}, got {d!r}")
            if force < 0:
                raise PushOptionError("force", f"{where}force is a magnitude >= 0 N when a direction is given, "
                                               f"got {force!r}")
            sign = 1.0 if d == "forward" else -1.0
        height = _number(spec, "height", where) if "height" in spec else None
        if height is not None and height < 0:
            raise PushOptionError("height", f"{where}height must be >= 0 m above the hip, got {height!r}")
        out.append(Push(onset, duration, sign * force, math.nan if height is None else height))
    out.sort(key=lambda p: p.start)
    for a, b in zip(out, out[1:]):
        if b.start < a.end:
            raise PushOptionError("onset", f"push: two pushes overlap ([{a.start}, {a.end}) and [{b.start}, {b.end}) s)")
    return tuple(out)


def push_info(p: Push | None, default_height: float) -> dict:
    """The push as ``info["push"]`` carries it, the same keys and finite values with or without one (so a
    vector of environments stacks them and equal episodes compare equal): ``force`` [N] magnitude,
    ``signed_force`` [N] (+ forward), ``onset`` [s], ``duration`` [s], ``direction`` ("forward", "backward";
    "none" without a push, then every number 0), ``height`` [m] above the hip (``default_height`` when the
    option gave none)."""
    if p is None:
        return {"force": 0.0, "signed_force": 0.0, "onset": 0.0, "duration": 0.0, "direction": "none",
                "height": 0.0}
    return {"force": abs(p.force), "signed_force": p.force, "onset": p.start, "duration": p.duration,
            "direction": "forward" if p.force >= 0 else "backward",
            "height": default_height if math.isnan(p.height) else p.height}


@dataclass(frozen=True)
class PushDistribution:
    """Random pushes for training: force magnitude uniform in [force_min, force_max] N, onset uniform in
    [onset_min, onset_max] s after the reset, duration drawn from ``durations`` [s], direction forward with
    probability ``p_forward``; with probability ``p_none`` no push at all."""

    force_min: float = 0.0
    force_max: float = 300.0
    onset_min: float = 0.2
    onset_max: float = 3.0
    durations: tuple[float, ...] = (0.025, 0.1)
    p_forward: float = 0.5
    p_none: float = 0.2

    def __post_init__(self):
        for k in ("force_min", "force_max", "onset_min", "onset_max", "p_forward", "p_none"):
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise PushOptionError(k, f"{k} must be a finite number >= 0, got {v!r}")
        if self.force_min > self.force_max or self.onset_min > self.onset_max:
            raise PushOptionError("force_min", "need force_min <= force_max and onset_min <= onset_max")
        if not self.durations or any(not (math.isfinite(d) and d > 0) for d in self.durations):
            raise PushOptionError("durations", f"durations must be finite numbers > 0, got {self.durations!r}")
        if self.p_forward > 1 or self.p_none > 1:
            raise PushOptionError("p_forward", "p_forward and p_none are probabilities in [0, 1]")

    def draw(self, rng: np.random.Generator) -> dict | None:
        """One push option (a mapping for ``reset(options={"push": ...})``) or None (no push)."""
        if rng.random() < self.p_none:
            return None
        return {"force": float(rng.uniform(self.force_min, self.force_max)),
                "onset": float(rng.uniform(self.onset_min, self.onset_max)),
                "duration": float(self.durations[int(rng.integers(len(self.durations)))]),
                "direction": "forward" if rng.random() < self.p_forward else "backward"}
