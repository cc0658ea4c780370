"""``python -m biped_controller.plugin list``: the registered controllers, one a line
(name, where it comes from, ``module:Class``, what it does). ``check NAME``: load one and report."""
from __future__ import annotations

import argparse
import sys

from biped_controller.plugin.interface import InterfaceError
from biped_controller.plugin.registry import (ControllerLoadError, UnknownControllerError, load_controller,
                                              load_registration, registered, summary)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m biped_controller.plugin",
                                 description="Controllers behind the controller interface.")
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list", help="the registered controllers, one a line")
    chk = sub.add_parser("check", help="load one controller and check it against the interface")
    chk.add_argument("name")
    args = ap.parse_args(argv)
    if args.cmd == "list":
        for r in registered():
            try:
                text = summary(load_registration(r))
            except (ControllerLoadError, InterfaceError) as exc:
                text = f"BROKEN: {exc}"
            print(f"{r.name:<16} {r.source:<24} {r.target:<56} {text}")
        return 0
    try:
        cls = load_controller(args.name)
    except (UnknownControllerError, ControllerLoadError, InterfaceError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.name}: {cls.__module__}.{cls.__qualname__} satisfies the interface: {summary(cls)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
