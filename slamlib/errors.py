"""Errors raised for bad input. Every message names the file, and the line where there is one."""

from __future__ import annotations

import os


class DataFormatError(ValueError):
    """Bad input data: ``str(err)`` reads ``path:line: message`` (or ``path: message`` without a line).

    Attributes
    ----------
    path : str
        The file that holds the bad data.
    line : int or None
        1-based line number inside ``path`` where the problem is, when the file is text.
    message : str
        What is wrong, in words that suggest the fix.
    """

    def __init__(self, path: str | os.PathLike, message: str, line: int | None = None):
        self.path = os.fspath(path)
        self.line = line
        self.message = message
        where = f"{self.path}:{line}" if line is not None else self.path
        super().__init__(f"{where}: {message}")


def bom_error(path: str | os.PathLike) -> DataFormatError:
    """The error for a text file that starts with a UTF-8 byte-order mark, which KITTI's files never have."""
    return DataFormatError(
        path,
        "starts with a UTF-8 byte-order mark (BOM, bytes EF BB BF), which KITTI's text files do not have "
        "(an editor added it?): save the file without a BOM",
        1,
    )


class BackendUnavailableError(RuntimeError):
    """A compute backend was asked for that this machine cannot run (e.g. ``backend="cuda"`` without a GPU)."""


class FolderBusyError(RuntimeError):
    """A folder another process is writing (:mod:`slamlib.atomic`): ``str(err)`` reads ``path: message``, the
    message naming the writing process."""

    def __init__(self, path: str | os.PathLike, message: str):
        self.path = os.fspath(path)
        self.message = message
        super().__init__(message)
