"""One writer per output folder: an advisory lock that a second ``reproduce`` or ``compare``
into the same folder meets, instead of training the same jobs into the same run folders.

The lock is ``fcntl.flock`` on ``FOLDER/.lock``: the kernel releases it when the holding
process ends, however it ends (a crash or a kill leaves no stale lock to clean up). The file
records the holder's pid and host for the error message; it is never deleted, only re-locked.
Workers of a Dask cluster do not take it: only the process that submits the jobs does.
"""
from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import socket
from pathlib import Path

from .errors import RunError

LOCK_NAME = ".lock"


@contextlib.contextmanager
def folder_lock(folder: str | Path, *, what: str):
    """Hold the lock of ``folder`` (created if missing) for the ``with`` block.

    Args:
        folder: the output folder.
        what: the command, for the error message (e.g. ``"reproduce"``).

    Raises:
        RunError: another live process holds it (its pid and host are named; nothing was changed).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 200, 0).decode(errors="replace").strip() or "unknown"
            raise RunError(f"another {what} is writing into {folder} ({holder}); wait for it to end or use "
                           "another --out (nothing was changed)") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()}\n".encode(), 0)
        yield path
    finally:
        os.close(fd)  # closing the descriptor releases the lock


def holds_work(folder: Path) -> bool:
    """Whether ``folder`` holds anything besides its lock."""
    return any(p.name != LOCK_NAME for p in Path(folder).iterdir())


@contextlib.contextmanager
def writer(folder: str | Path, *, what: str, keep=holds_work):
    """:func:`folder_lock` for a command that may create ``folder``: when the ``with`` block fails
    and this call created the folder, the folder is removed again unless ``keep(folder)`` says it
    holds work worth keeping (default: anything besides the lock), so a corrected retry starts
    clean and a failed call leaves nothing behind.

    Args:
        folder: the output folder; what: the command, for the error message; keep: Path -> bool.
    """
    folder = Path(folder)
    created = not folder.exists()
    try:
        with folder_lock(folder, what=what) as path:
            yield path
    except BaseException:
        if created and folder.is_dir() and not keep(folder):
            shutil.rmtree(folder, ignore_errors=True)
        raise
