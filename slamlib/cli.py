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
            # an option given again and again collects a list by design (action="append")
            and not isinstance(action.default, list)
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


#: Times a signal swallowed in a destructor is sent again, and the pause before each time (s).
SIGNAL_REDELIVERIES = 5
REDELIVERY_DELAY_S = 0.01


class Terminated(BaseException):
    """Raised in the main thread on SIGTERM, so that a command unwinds as on Ctrl-C: its ``finally`` blocks remove
    its temporary files and release its locks (:mod:`slamlib.atomic`)."""


class _SignalsAsExceptions:
    """For the ``with`` block, in the main thread: SIGINT raises ``KeyboardInterrupt`` and SIGTERM
    :class:`Terminated`, and each signal is remembered as it arrives (``received``), because the exception may
    not reach the command as itself: a C extension being imported turns it into ``ImportError``, and one raised in
    a destructor (llvmlite's and open3d's objects are collected at any moment) is swallowed. Python would report
    that as unraisable; here the report is left out and the signal sent again a moment later, up to
    :data:`SIGNAL_REDELIVERIES` times, so that it lands in the command's own code. A command that still finishes
    ends as the signal asked."""

    def __enter__(self):
        self.received, self.previous, self.timers, self.closing = [], {}, [], False
        self.hook = sys.unraisablehook
        if threading.current_thread() is threading.main_thread():  # signals reach it only
            for sig in (signal.SIGINT, signal.SIGTERM):
                if signal.getsignal(sig) is not signal.SIG_IGN:
                    self.previous[sig] = signal.signal(sig, self._raise)
            sys.unraisablehook = self._unraisable
        return self

    def _raise(self, signum, frame):
        self.received.append(signum)
        if not self.closing:  # once the command is over, a late one is only counted
            raise Terminated if signum == signal.SIGTERM else KeyboardInterrupt

    def _unraisable(self, unraisable):
        if not (
            self.received
            and isinstance(unraisable.exc_value, (Terminated, KeyboardInterrupt))
        ):
            self.hook(unraisable)
        elif len(self.received) <= SIGNAL_REDELIVERIES:
            again = threading.Timer(
                REDELIVERY_DELAY_S, signal.raise_signal, (self.received[-1],)
            )
            again.daemon = True
            again.start()
            self.timers.append(again)

    def __exit__(self, *exc):
        # a redelivery still on its way arrives now, while the handler only counts it
        self.closing = True
        for timer in self.timers:
            timer.cancel()
            timer.join()
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)
        sys.unraisablehook = self.hook
        return False

    def ended_by(self, exc: BaseException | None):
        """The signal that ends the command: the first received, or the one ``exc`` stands for."""
        if self.received:
            return self.received[0]
        if isinstance(exc, KeyboardInterrupt):
            return signal.SIGINT
        return signal.SIGTERM if isinstance(exc, Terminated) else None


def _signal_exit(name: str, sig) -> int:
    """The one line and the exit code of a command ended by ``sig``."""
    if sig == signal.SIGINT:
        print(
            f"\n{name}: interrupted (Ctrl-C); nothing half written is left",
            file=sys.stderr,
        )
        return EXIT_SIGINT
    print(f"{name}: terminated (SIGTERM); nothing half written is left", file=sys.stderr)
    return EXIT_SIGTERM


def _run_command(argv: list[str] | None) -> int:
    """Parse ``argv`` and run its command, with signals and the errors every command shares as one line on stderr
    and an exit code: Ctrl-C 130, SIGTERM 143, a folder another process writes or a full disk 1. The signal
    handlers are in place before the commands' modules load (:class:`_SignalsAsExceptions`), so a signal during
    the imports ends the same way.
    """
    from slamlib.atomic import describe_os_error, write_error
    from slamlib.errors import FolderBusyError

    started = time.perf_counter()
    name = "slamlib"
    with _SignalsAsExceptions() as signals:
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
            code = int(args._main(args) or 0)
        except BaseException as exc:
            sig = signals.ended_by(exc)
            if sig is not None:
                return _signal_exit(name, sig)
            if isinstance(exc, OSError) and exc.errno == errno.ENOSPC:
                # with the free space left there
                exc = write_error(exc.filename, exc) if exc.filename else exc
                print(f"{name}: {describe_os_error(exc)}", file=sys.stderr)
                return EXIT_ERROR
            if isinstance(exc, FolderBusyError):
                print(f"{name}: {exc}", file=sys.stderr)
                return EXIT_ERROR
            raise
        # a signal swallowed on the way (in a destructor): the command finished, and says how it was asked to end
        sig = signals.ended_by(None)
        return code if sig is None else _signal_exit(name, sig)


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
