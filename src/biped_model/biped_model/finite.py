"""The one check that a setting or an input is a finite real number (optionally an integer, within
bounds), for every pure module of the project (``biped_sim`` and ``biped_controller`` alike). Pure Python +
NumPy, no ROS. Numba kernels keep their own inline checks (they cannot call Python).

:func:`finite_number` accepts a real number (``numbers.Real``: ``int``, ``float``, NumPy scalars; never a
``bool``) that is finite (not NaN, not +-inf), an integer when ``integer`` is set, and within the bounds
given (``above``: > ``above``; ``at_least``: >= ``at_least``; ``at_most``: <= ``at_most``); otherwise it
raises ``error(message)`` (by default :class:`NumberError`, a ``ValueError``) with the caller's ``message``
or the standard one, ``"<name> must be a finite number > 0, got <value!r>"`` ("an integer" for integers). A
caller with its own error type (a ``ValueError`` subclass naming its domain, or a callable building one
from the message) passes it as ``error``, so ``except ValueError`` and the domain's own ``except`` both
hold.

:func:`finite_array` is the same check on every element of an array (``positive``: every element > 0).
"""
from __future__ import annotations

import math
import numbers
from typing import Callable

import numpy as np


class NumberError(ValueError):
    """A value that must be a finite real number (an integer, within bounds) is not; the message names it."""


def _bounds(above: float | None, at_least: float | None, at_most: float | None) -> str:
    parts = []
    if above is not None:
        parts.append(f"> {above:g}")
    if at_least is not None:
        parts.append(f">= {at_least:g}")
    if at_most is not None:
        parts.append(f"<= {at_most:g}")
    return (" " + " and ".join(parts)) if parts else ""


def finite_number(value, name: str, *, above: float | None = None, at_least: float | None = None,
                  at_most: float | None = None, integer: bool = False, message: str | None = None,
                  error: Callable[[str], ValueError] = NumberError) -> float:
    """``float(value)`` when ``value`` is a finite real number (not a bool), an integer if ``integer``, and
    within the bounds; else raises ``error(message)`` (``message`` None: the standard message of the module
    docstring, which names ``name``, the bounds and ``value``)."""
    ok = isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)) and math.isfinite(value) \
        and (not integer or value == int(value)) \
        and (above is None or value > above) and (at_least is None or value >= at_least) \
        and (at_most is None or value <= at_most)
    if not ok:
        if message is None:
            kind = "an integer" if integer else "a finite number"
            message = f"{name} must be {kind}{_bounds(above, at_least, at_most)}, got {value!r}"
        raise error(message)
    return float(value)


def finite_array(values, name: str, *, positive: bool = False, message: str | None = None,
                 error: Callable[[str], ValueError] = NumberError) -> np.ndarray:
    """``values`` as a float array when every element is finite (and > 0 if ``positive``); else raises
    ``error(message)`` (``message`` None: ``"<name> must be finite[ and positive], got <values>"``)."""
    a = np.asarray(values, dtype=float)
    if not (np.all(np.isfinite(a)) and (not positive or np.all(a > 0))):
        raise error(message if message is not None
                    else f"{name} must be finite{' and positive' if positive else ''}, got {values}")
    return a
