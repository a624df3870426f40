"""The ``slamlib`` console script: ``slamlib <command> [options]``; ``slamlib --help`` lists the commands."""

from __future__ import annotations

import argparse
import importlib
import sys

from slamlib import __version__
from slamlib.commands import COMMANDS


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="slamlib",
        description="Particle-filter SLAM from 1D to 3D KITTI drives, with Numba CPU and CUDA kernels.",
    )
    parser.add_argument("--version", action="version", version=f"slamlib {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="<command>")
    parser.commands = {}  # name -> its sub-parser, for the checks in main()
    for name, module_name in COMMANDS.items():
        module = importlib.import_module(module_name)
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_main=module.main)
        parser.commands[name] = p
    return parser


def _check_single_values(
    parser: argparse.ArgumentParser, args: argparse.Namespace
) -> None:
    """Exit with argparse's usage error naming the option when a one-value option came back as a list: Python
    3.11's argparse turns ``--option=--`` into ``[]``, which the commands would otherwise fail on with a
    TypeError far from the command line."""
    for action in parser._actions:
        if (
            action.option_strings
            and action.nargs is None
            and isinstance(getattr(args, action.dest, None), list)
        ):
            parser.error(
                f"argument {'/'.join(action.option_strings)}: expected one value"
            )


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    # as typed, for results that record their command
    args.argv = list(sys.argv[1:] if argv is None else argv)
    if args.command is None:
        parser.print_help()
        return 0
    _check_single_values(parser.commands[args.command], args)
    return int(args._main(args) or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
