"""A controller's options as text: ``KEY=VALUE`` items, the one parser of the study commands' ``--option`` and
the controller node's ``controller_options`` parameter.

An item is ``KEY=VALUE`` split at its first ``=``: the value is a switch for ``true`` / ``false`` (bool, any
case: ``whole_body=false``), a float where Python's ``float`` reads it (``policy_period=0.02`` -> 0.02), else the
text as given (a word or a path: ``file=policies/x/policy.onnx``).
An item without ``=``, with an empty key or an empty value raises :class:`ControllerOptionError` naming the
item; a list giving one key twice raises it naming the key (a second value would silently win otherwise).
"""
from __future__ import annotations

from typing import Iterable


#: the words an option's value reads as a switch (any case)
SWITCH_WORDS = {"true": True, "false": False}


class ControllerOptionError(ValueError):
    """A controller option that is not ``KEY=VALUE`` (the message names the item, and ``where`` it came from)."""


def parse_option(text: str, where: str = "--option") -> tuple[str, float | bool | str]:
    """``KEY=VALUE`` -> (key, value): the value a switch, a float where it reads as one, else the text (module
    docstring);
    ``where`` (the flag or parameter the item came from) starts the error message."""
    if not isinstance(text, str):
        raise ControllerOptionError(f"{where} takes KEY=VALUE text, got {text!r}")
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise ControllerOptionError(f"{where} takes KEY=VALUE, got {text!r}")
    if value.strip().lower() in SWITCH_WORDS:
        return key, SWITCH_WORDS[value.strip().lower()]
    try:
        return key, float(value)
    except ValueError:
        if not value:
            raise ControllerOptionError(f"{where} {key}: the value is empty") from None
        return key, value


def parse_options(items: Iterable[str], where: str = "--option") -> dict[str, float | bool | str]:
    """The options of ``KEY=VALUE`` items (:func:`parse_option` each); a key given twice raises
    :class:`ControllerOptionError` naming it."""
    out: dict[str, float | bool | str] = {}
    for text in items:
        key, value = parse_option(text, where)
        if key in out:
            raise ControllerOptionError(f"{where} {key}: given twice ({out[key]!r} and {value!r})")
        out[key] = value
    return out
