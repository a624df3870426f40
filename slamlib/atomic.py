"""Outputs that appear whole or not at all, written by one process at a time.

A folder of results (a synthetic drive, a sequence, a run's ``--out``) is written into a temporary sibling
``.NAME.PID.partial`` and published by renames, never file by file:

* ``NAME`` absent (or an empty folder): one ``rename(2)`` of the temporary folder onto it;
* ``NAME`` present: ``NAME`` -> ``.NAME.PID.old``, the temporary folder -> ``NAME``, then the entries of the old
  folder that the writer does not own (a user's notes, a ``slamlib run --out DRIVE/out`` folder inside a drive)
  moved back into ``NAME`` and the old folder removed.

A reader therefore sees the old folder, no folder, or the new one, never a mixture. While it writes, the process
holds an exclusive OS lock (``flock(2)``) on ``.NAME.lock`` beside the folder, holding its process id: a second
writer is told which process writes it (:class:`~slamlib.errors.FolderBusyError`), or waits. Temporaries left by
a process that died (``SIGKILL``, power loss) are recognised by the lock, since a writer holding it is the only
one that can have made them, and are cleaned by the next writer: partial folders removed, an old folder whose
swap was cut short put back.

POSIX only (``fcntl``), like the rest of slamlib's tooling; the temporary folders are siblings, so every rename
stays on one file system and is atomic.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from slamlib.errors import FolderBusyError

__all__ = [
    "LOCK_POLL_S",
    "atomic_folder",
    "atomic_file",
    "folder_lock",
    "publish_folder",
    "clean_stale",
    "lock_path",
    "free_bytes",
    "write_error",
    "describe_os_error",
]

#: Seconds between two tries of a waiting writer.
LOCK_POLL_S = 0.2
PARTIAL_SUFFIX = ".partial"
OLD_SUFFIX = ".old"


def lock_path(folder) -> Path:
    """The lock file of ``folder``: ``.NAME.lock`` beside it."""
    folder = Path(folder)
    return folder.parent / f".{folder.name}.lock"


def _holder(path: Path) -> str:
    try:
        pid = path.read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError):
        pid = ""
    return f"process {pid}" if pid.isdigit() else "another process"


@contextlib.contextmanager
def folder_lock(
    folder, wait: bool = False, what: str = "it", timeout: float | None = None
) -> Iterator[Path]:
    """Hold the exclusive lock of ``folder`` (:func:`lock_path`) for the ``with`` block.

    Another holder makes it raise :class:`~slamlib.errors.FolderBusyError` ("FOLDER is being written by process
    N"), or with ``wait`` print that once to stderr and wait (at most ``timeout`` seconds when given, quietly).
    ``what`` names the option that chose the folder, for the message. The lock file is removed on release; a
    waiter that then finds it gone (or replaced) tries again on the new file, so two holders never overlap.
    """
    import fcntl

    folder = Path(folder)
    path = lock_path(folder)
    path.parent.mkdir(parents=True, exist_ok=True)
    told = False
    give_up = None if timeout is None else time.monotonic() + timeout
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            message = f"{folder} is being written by {_holder(path)}"
            if not wait or (give_up is not None and time.monotonic() > give_up):
                raise FolderBusyError(
                    folder, f"{message}; wait for it to finish or choose another {what}"
                ) from None
            if not told and give_up is None:
                print(f"{message}: waiting for it to finish", file=sys.stderr, flush=True)
                told = True
            time.sleep(LOCK_POLL_S)
            continue
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if (
            not same
        ):  # the holder before us removed it as we opened it: lock the current file
            os.close(fd)
            continue
        break
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode("ascii"))
        yield path
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)
        os.close(fd)


def _siblings(folder: Path, suffix: str) -> list[Path]:
    prefix = f".{folder.name}."
    if not folder.parent.is_dir():
        return []
    return sorted(
        p
        for p in folder.parent.iterdir()
        if p.name.startswith(prefix) and p.name.endswith(suffix) and p.is_dir()
    )


def clean_stale(folder, keep: Callable[[str], bool] = lambda name: True) -> list[Path]:
    """Remove the temporaries a dead writer of ``folder`` left; call with the lock held. Returns what it removed.

    ``.NAME.*.partial`` folders are removed. An ``.NAME.*.old`` folder (a swap cut short) is put back as
    ``NAME`` when ``NAME`` is missing, otherwise its entries that ``keep(path)`` accepts and ``NAME`` lacks are
    moved into ``NAME`` before it is removed: the user's files survive any kill point."""
    folder = Path(folder)
    removed = []
    for tmp in _siblings(folder, PARTIAL_SUFFIX):
        shutil.rmtree(tmp, ignore_errors=True)
        removed.append(tmp)
    for old in _siblings(folder, OLD_SUFFIX):
        if not folder.exists():
            os.rename(old, folder)
            continue
        _move_kept(old, folder, keep)
        shutil.rmtree(old, ignore_errors=True)
        removed.append(old)
    return removed


def _move_kept(src: Path, dst: Path, keep: Callable[[str], bool], rel: str = "") -> None:
    """Move the entries of ``src`` that ``keep(relative path)`` accepts into ``dst``, where ``dst`` lacks them;
    into a folder both have, entry by entry."""
    for entry in sorted(src.iterdir()):
        path, target = rel + entry.name, dst / entry.name
        if (
            entry.is_dir()
            and not entry.is_symlink()
            and target.is_dir()
            and not target.is_symlink()
        ):
            _move_kept(entry, target, keep, path + "/")
        elif keep(path) and not os.path.lexists(target):
            os.rename(entry, target)


def publish_folder(tmp, folder, keep: Callable[[str], bool] = lambda name: False) -> None:
    """Put the finished folder ``tmp`` in place of ``folder`` by renames (module docstring); the entries of an
    existing ``folder`` that ``keep(path)`` accepts (``path`` relative to the folder, ``/``-separated) move into
    the new one, into its sub-folders where both have one. Call with the lock held."""
    tmp, folder = Path(tmp), Path(folder)
    try:
        os.rename(tmp, folder)  # absent, or an empty folder: one atomic rename
        return
    except OSError as exc:
        if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR, errno.EISDIR):
            raise
    if not folder.is_dir() or folder.is_symlink():
        raise FileExistsError(f"{folder} exists and is not a folder")
    old = folder.parent / f".{folder.name}.{os.getpid()}{OLD_SUFFIX}"
    os.rename(folder, old)
    os.rename(tmp, folder)
    _move_kept(old, folder, keep)
    shutil.rmtree(old)


@contextlib.contextmanager
def atomic_folder(
    folder,
    keep: Callable[[str], bool] = lambda name: False,
    wait: bool = False,
    what: str = "it",
    locked: bool = False,
) -> Iterator[Path]:
    """Write ``folder`` whole or not at all: lock it (:func:`folder_lock`; ``locked``: the caller holds the lock
    already), clean a dead writer's temporaries
    (:func:`clean_stale`), yield an empty temporary sibling to write into, and on a normal exit publish it
    (:func:`publish_folder`). On any exception (``KeyboardInterrupt`` and ``SystemExit`` included) the temporary
    folder is removed and ``folder`` stays as it was. ``keep(path)``: the entries of an existing ``folder`` that
    are not the writer's own and move into the new one (:func:`publish_folder`)."""
    folder = Path(folder)
    lock = contextlib.nullcontext() if locked else folder_lock(folder, wait, what)
    with lock:
        clean_stale(folder, keep)
        tmp = folder.parent / f".{folder.name}.{os.getpid()}{PARTIAL_SUFFIX}"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)
        try:
            yield tmp
            publish_folder(tmp, folder, keep)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)


def atomic_file(path, data: bytes) -> None:
    """Write ``data`` to ``path`` whole or not at all: a temporary sibling, flushed, then ``os.replace``."""
    path = Path(path)
    tmp = path.parent / f".{path.name}.{os.getpid()}{PARTIAL_SUFFIX}"
    try:
        with open(tmp, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)


def free_bytes(path) -> int | None:
    """Free bytes on the file system of ``path`` (its nearest existing folder), or None when it cannot be told."""
    path = Path(path)
    for folder in (path, *path.parents):
        if folder.is_dir():
            try:
                return shutil.disk_usage(folder).free
            except OSError:
                return None
    return None


def _size(n: int | None) -> str:
    if n is None:
        return "an unknown amount"
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} bytes"


def write_error(path, exc: OSError) -> OSError:
    """``exc`` (raised while writing ``path``) as one ``OSError`` that names ``path`` and, when the disk is full
    (``ENOSPC``, or the short write numpy's ``tofile`` reports as "N requested and M written"), says so with the
    free space left. Raise it ``from None``."""
    short = "requested and" in str(exc) and "written" in str(exc)
    if exc.errno == errno.ENOSPC or short:
        return OSError(
            errno.ENOSPC,
            f"no space left on the disk ({_size(free_bytes(path))} free there)",
            os.fspath(path),
        )
    if getattr(exc, "filename", None):
        return exc
    return OSError(exc.errno, exc.strerror or str(exc), os.fspath(path))


def describe_os_error(exc: OSError, where=None) -> str:
    """One line for ``exc``: its message and the file it names, without Python's ``[Errno N]`` prefix. An error
    that names no file (a failed ``write`` or ``close``) is told as :func:`write_error` tells it for the folder
    ``where`` (given by the caller, who names it already)."""
    if not exc.filename and where is not None:
        exc = write_error(where, exc)
        return exc.strerror
    what = exc.strerror or str(exc)
    return f"{exc.filename}: {what}" if exc.filename else what
