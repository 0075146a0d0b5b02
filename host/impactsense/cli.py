"""The `impactsense` command line.

Each sub-command lives in its own module under `impactsense.commands`; a module provides
`register(subparsers)`, which adds its parser and sets `func` (called with the parsed args; returns an exit
code), and an integer `ORDER` (its place in `--help`). Adding a command is adding a module.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from . import __version__
from .errors import ImpactSenseError

from . import commands


def command_modules():
    """The command modules, in `--help` order."""
    mods = [importlib.import_module(f"{commands.__name__}.{m.name}")
            for m in pkgutil.iter_modules(commands.__path__) if not m.name.startswith("_")]
    return sorted(mods, key=lambda m: (getattr(m, "ORDER", 100), m.__name__))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="impactsense",
        description="Impact localisation and energy classification on a PZT-instrumented plate.",
    )
    parser.add_argument("--version", action="version", version=f"impactsense {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in command_modules():
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except ImpactSenseError as exc:
        print(f"impactsense {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
