"""The ``reflexarm`` command line.

Sub-commands are contributed by the modules of :mod:`reflexarm._cli`, each with a
``register(subparsers)`` function: ``simulate`` (demo, simulate), ``identify`` (excite, identify,
validate), ``experiments`` (efc-step, compliance-loss, mode-table, sweep), ``tools`` (bench, robots).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings
from collections.abc import Sequence

from reflexarm import __version__
from reflexarm.errors import ReflexArmError

_COMMAND_MODULES = (
    "simulate",
    "identify",
    "experiments",
    "tools",
    "thresholds",
    "isolation",
    "reaction_study",
    "detection",
    "detect",
    "pfl",
    "ros",
)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every sub-command registered."""
    parser = argparse.ArgumentParser(
        prog="reflexarm",
        description="Impedance control, momentum observer, collision handling and identification for robot arms.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in _COMMAND_MODULES:
        try:
            module = importlib.import_module(f"reflexarm._cli.{name}")
        except ModuleNotFoundError as e:
            if e.name != f"reflexarm._cli.{name}":
                raise
            continue
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``reflexarm`` script; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)

    def format_warning(message: Warning | str, category: type[Warning], *_: object, **__: object) -> str:
        # a user reads "reflexarm CMD: warning: RobotFileWarning: ...", not the source line that warned
        return f"reflexarm {args.command}: warning: {category.__name__}: {message}\n"

    default_format = warnings.formatwarning
    warnings.formatwarning = format_warning  # type: ignore[assignment]
    try:
        return int(args.func(args) or 0)
    except ReflexArmError as e:
        print(f"reflexarm {args.command}: error: {e}", file=sys.stderr)
        return 2
    finally:
        warnings.formatwarning = default_format


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
