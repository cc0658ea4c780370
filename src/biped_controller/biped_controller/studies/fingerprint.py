"""Fingerprint of the rigid plant's closed loop: one hash over the records of a fixed set of runs.

    python -m biped_controller.studies.fingerprint [--skip-prefix PREFIX ...]

A refactoring that must not change behaviour prints the same line before and after (on the same
machine: the hash covers every bit of every float, so a different CPU or library build may differ).
The runs: walks, pushes and falls in the paper's four modes and the two baseline modes, with the
compiled closed loop on and off (the objects and the compiled loop must agree with each other too:
each pair is also compared). Every field of every ``StepRecord``, ``ImpactRecord`` and controller
status enters the hash, in order, except status fields named with a ``--skip-prefix`` (a field added
on purpose is skipped so that the rest can still be compared).

Each run is also made a third way, through the controller interface every consumer uses (the mode's
built-in class, ``plugin.builtin``, on the generic loop ``plugin.loop``): its records, impacts and outcome
(its status is the interface's mapping, not hashed) must equal the compiled loop's bit for bit, so the compiled
path stays an optimisation of the one route. It is compared, not hashed: the fingerprint line is the same.
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import sys

import numpy as np

from biped_sim.plant.push import Push
from biped_controller.closed_loop.runner import run
from biped_controller.plugin import loop as plugin_loop

# (name, steps, mode, pushes)
RUNS = (
    ("walk-both", 4, "both", ()),
    ("walk-none", 3, "none", ()),
    ("push-both", 4, "both", (Push(0.9, 0.025, 300.0),)),
    ("push-tau", 4, "tau", (Push(0.9, 0.025, 200.0),)),
    ("push-p", 4, "p", (Push(0.9, 0.025, 150.0),)),
    ("back-both", 4, "both", (Push(1.2, 0.025, -150.0),)),
    ("fall-both", 4, "both", (Push(0.9, 0.025, 1500.0),)),
    ("push-wbc", 3, "wbc", (Push(0.9, 0.025, 150.0),)),
    ("push-hybrid", 3, "hybrid", (Push(0.9, 0.025, 300.0),)),
)


def feed(h, value) -> None:
    """Every bit of ``value`` into the hash ``h`` (arrays and floats as float64 bytes, anything else by repr)."""
    if isinstance(value, np.ndarray):
        h.update(np.ascontiguousarray(value, dtype=np.float64).tobytes())
    elif isinstance(value, float):
        h.update(np.float64(value).tobytes())
    else:
        h.update(repr(value).encode())


def digest(result, skip: tuple[str, ...], statuses: bool = True) -> str:
    """sha256 (hex) of every field of a ``RunResult``'s records, impacts and statuses (status fields starting
    with one of ``skip`` left out; none with ``statuses`` False) and its outcome."""
    h = hashlib.sha256()
    for rec in result.records:
        for f in dataclasses.fields(rec):
            feed(h, getattr(rec, f.name))
    for imp in result.impacts:
        for f in dataclasses.fields(imp):
            feed(h, getattr(imp, f.name))
    for st in result.statuses if statuses else ():
        for f in dataclasses.fields(st):
            if not f.name.startswith(skip):
                feed(h, getattr(st, f.name))
    feed(h, (result.steps_walked, result.fallen, result.fall_cause, result.fall_detail, float(result.fall_time)))
    return h.hexdigest()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="fingerprint", description=__doc__.split("\n\n")[0])
    ap.add_argument("--skip-prefix", action="append", default=[], help="status fields to leave out (repeatable)")
    args = ap.parse_args(argv)
    skip = tuple(args.skip_prefix)
    total = hashlib.sha256()
    disagree = []
    for name, steps, mode, pushes in RUNS:
        digests = {}
        for compiled in (True, False):
            r = run(steps, mode, pushes, compiled_loop=compiled)
            if compiled:
                r_compiled = r
            digests[compiled] = digest(r, skip)
            print(f"{name:12s} compiled={compiled!s:5s} steps={r.steps_walked} fallen={r.fallen} "
                  f"{digests[compiled][:16]}", flush=True)
        if digests[True] != digests[False]:
            disagree.append(name)
        iface = plugin_loop.run(mode, steps, pushes)        # the built-in class through the interface
        same = iface.fault is None and digest(iface, skip, statuses=False) == digest(r_compiled, skip, statuses=False)
        print(f"{name:12s} interface     steps={iface.steps_walked} fallen={iface.fallen} "
              f"{'same records as the compiled loop' if same else 'DIFFERENT records'}", flush=True)
        if not same:
            disagree.append(f"{name} (interface)")
        total.update(digests[True].encode())
        total.update(digests[False].encode())
    print(f"fingerprint {total.hexdigest()}")
    if disagree:
        print(f"compiled loop and objects (or the interface) disagree: {', '.join(disagree)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
