"""The ``slamlib`` console script: ``slamlib <command> [options]``; ``slamlib --help`` lists the commands."""

from __future__ import annotations

import argparse
import errno
import importlib
import signal
import sys
import threading
import time

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


#: Exit codes of a command ended by a signal, as a shell reports them: 128 + SIGINT (Ctrl-C), 128 + SIGTERM.
EXIT_SIGINT = 128 + signal.SIGINT
EXIT_SIGTERM = 128 + signal.SIGTERM
#: Exit code of a command that stopped on an error it reported in one line.
EXIT_ERROR = 1


class Terminated(BaseException):
    """Raised in the main thread on SIGTERM, so that a command unwinds as on Ctrl-C: its ``finally`` blocks remove
    its temporary files and release its locks (:mod:`slamlib.atomic`)."""


def _run_command(argv: list[str] | None) -> int:
    """Parse ``argv`` and run its command, with signals and the errors every command shares as one line on stderr
    and an exit code: Ctrl-C 130, SIGTERM 143, a folder another process writes or a full disk 1. The signal
    handlers are in place before the commands' modules load, so a signal during the imports ends the same way.

    A signal is remembered as it arrives: the exception its handler raises may surface as another one (a C
    extension being imported turns it into ``ImportError``), and the command still ends as the signal asks.
    """
    from slamlib.atomic import describe_os_error, write_error
    from slamlib.errors import FolderBusyError

    started = time.perf_counter()
    name = "slamlib"
    received = []

    def on_signal(signum, frame):
        received.append(signum)
        raise Terminated if signum == signal.SIGTERM else KeyboardInterrupt

    previous = {}
    if threading.current_thread() is threading.main_thread():  # signals reach it only
        for sig in (signal.SIGINT, signal.SIGTERM):
            if signal.getsignal(sig) is not signal.SIG_IGN:
                previous[sig] = signal.signal(sig, on_signal)
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        # as typed, for results that record their command
        args.argv = list(sys.argv[1:] if argv is None else argv)
        args.started = started  # for the start-up time a command reports
        if args.command is None:
            parser.print_help()
            return 0
        name = f"slamlib {args.command}"
        _check_single_values(parser.commands[args.command], args)
        return int(args._main(args) or 0)
    except BaseException as exc:
        if isinstance(exc, KeyboardInterrupt) or signal.SIGINT in received[:1]:
            print(
                f"\n{name}: interrupted (Ctrl-C); nothing half written is left",
                file=sys.stderr,
            )
            return EXIT_SIGINT
        if isinstance(exc, Terminated) or signal.SIGTERM in received[:1]:
            print(
                f"{name}: terminated (SIGTERM); nothing half written is left",
                file=sys.stderr,
            )
            return EXIT_SIGTERM
        if isinstance(exc, FolderBusyError) or (
            isinstance(exc, OSError) and exc.errno == errno.ENOSPC
        ):
            # with the free space left there
            if isinstance(exc, OSError) and exc.filename:
                exc = write_error(exc.filename, exc)
            what = describe_os_error(exc) if isinstance(exc, OSError) else exc
            print(f"{name}: {what}", file=sys.stderr)
            return EXIT_ERROR
        raise
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def main(argv: list[str] | None = None) -> int:
    """Run ``slamlib`` with the arguments ``argv`` (default ``sys.argv[1:]``); returns the exit code."""
    return _run_command(argv)


def console() -> None:
    """The ``slamlib`` console script: :func:`main`, then exit with its code. A command ended by a signal exits at
    once (``os._exit``) after flushing its output, as a process killed by it would: a C extension interrupted in
    its initialisation (open3d's) would otherwise end the interpreter's teardown with its own exit code 1."""
    import os

    code = main()
    if code in (EXIT_SIGINT, EXIT_SIGTERM):
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":  # pragma: no cover
    console()
