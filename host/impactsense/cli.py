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
        if getattr(args, "scheduler", None):
            from .sim import executor

            executor.set_scheduler(args.scheduler)
        return int(args.func(args) or 0)
    except ImpactSenseError as exc:
        print(f"impactsense {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:     # the reader of our output went away (`| head`)
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except KeyboardInterrupt:
        print(f"impactsense {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001  (a bug or an unforeseen input: one line, the details in a log)
        log = _log_traceback(argv)
        print(f"impactsense {args.command}: internal error: {type(exc).__name__}: {str(exc)[:300]} "
              f"(details in {log})", file=sys.stderr)
        return 1


def _log_traceback(argv) -> str:
    """Appends the current exception's traceback to the error log; returns its path."""
    import os
    import tempfile
    import time
    import traceback
    from pathlib import Path

    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "impactsense"
    for folder in (base, Path(tempfile.gettempdir())):
        try:
            folder.mkdir(parents=True, exist_ok=True)
            path = folder / "impactsense-errors.log"
            with open(path, "a") as fh:
                fh.write(f"--- {time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())} impactsense "
                         f"{' '.join(map(str, argv if argv is not None else sys.argv[1:]))}\n")
                fh.write(traceback.format_exc())
            return str(path)
        except OSError:
            continue
    return "(no writable log folder)"


if __name__ == "__main__":
    sys.exit(main())
