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
    for name, module_name in COMMANDS.items():
        module = importlib.import_module(module_name)
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_main=module.main)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    return int(args._main(args) or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
