"""SIGTERM stops a command as Ctrl-C does: the work unwinds and what is finished is kept.

A process killed with ``kill`` (SIGTERM, what a job scheduler or a closing terminal sends) would
otherwise die at once, with no message and its wall time unrecorded. Inside
:func:`sigterm_interrupts` the signal raises :class:`Terminated`, a ``KeyboardInterrupt``, so every
path that keeps finished work on Ctrl-C keeps it on SIGTERM too, and the CLI names it.
"""
from __future__ import annotations

import contextlib
import signal
import threading


class Terminated(KeyboardInterrupt):
    """The process was sent SIGTERM."""


@contextlib.contextmanager
def sigterm_interrupts():
    """Within the block, SIGTERM raises :class:`Terminated`; the previous handler comes back after
    it. Only in the main thread, where Python delivers signals (elsewhere nothing changes)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, _frame):
        raise Terminated(f"signal {signum}")

    old = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)
