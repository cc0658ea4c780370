"""The one finite-number check (``biped_model.finite``): what it accepts, what it rejects, the
messages it writes and the error types it raises."""
from __future__ import annotations

import math

import numpy as np
import pytest

from biped_model.finite import NumberError, finite_array, finite_number


class DomainError(ValueError):
    """A caller's own error type."""


@pytest.mark.parametrize("value", [0.5, 3, np.float64(2.0), np.int64(4), 1e300])
def test_accepts_finite_reals_and_returns_a_float(value):
    out = finite_number(value, "x", above=0)
    assert isinstance(out, float) and out == float(value)


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf, True, False, "1.0", None, [1.0]])
def test_rejects_what_is_not_a_finite_real(value):
    with pytest.raises(NumberError) as info:
        finite_number(value, "gain")
    assert isinstance(info.value, ValueError)
    assert str(info.value) == f"gain must be a finite number, got {value!r}"


def test_bounds_and_their_messages():
    assert finite_number(0, "m", at_least=0) == 0.0
    with pytest.raises(NumberError, match=r"^m must be a finite number > 0, got 0$"):
        finite_number(0, "m", above=0)
    with pytest.raises(NumberError, match=r"^m must be a finite number >= 0, got -1e-12$"):
        finite_number(-1e-12, "m", at_least=0)
    assert finite_number(0.05, "T", above=0, at_most=0.05) == 0.05
    with pytest.raises(NumberError, match=r"^T must be a finite number > 0 and <= 0.05, got 0.06$"):
        finite_number(0.06, "T", above=0, at_most=0.05)


def test_integers():
    assert finite_number(3.0, "n", integer=True, at_least=0) == 3.0
    with pytest.raises(NumberError, match=r"^n must be an integer >= 0, got 2.5$"):
        finite_number(2.5, "n", integer=True, at_least=0)
    with pytest.raises(NumberError, match=r"^n must be an integer >= 0, got -1$"):
        finite_number(-1, "n", integer=True, at_least=0)


def test_the_callers_error_type_and_message():
    with pytest.raises(DomainError, match=r"^custom$"):
        finite_number(math.nan, "x", error=DomainError, message="custom")
    # a callable building the error from the message (an error with a field argument)
    with pytest.raises(DomainError) as info:
        finite_number(math.inf, "x", error=lambda m: DomainError("x", m))
    assert info.value.args == ("x", "x must be a finite number, got inf")


def test_arrays():
    out = finite_array([1.0, 2.0], "W", positive=True)
    assert out.dtype == float and out.tolist() == [1.0, 2.0]
    finite_array([0.0, -1.0], "W")
    with pytest.raises(NumberError, match=r"^W must be finite and positive"):
        finite_array([1.0, 0.0], "W", positive=True)
    with pytest.raises(NumberError, match=r"^W must be finite, got"):
        finite_array([1.0, math.nan], "W")
    with pytest.raises(DomainError):
        finite_array(np.array([math.inf]), "W", error=DomainError)
