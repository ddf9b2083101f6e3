"""Refuse a request whose arrays cannot fit in memory, before the work that would fill them.

NumPy refuses one huge allocation at once (a MemoryError the CLI names), but a request whose
arrays are built piece by piece, or after minutes of other work, would run that long first.
:func:`check_fits` compares the bytes a request will need with the machine's physical memory.
"""
from __future__ import annotations

import os


def physical_memory_bytes() -> int | None:
    """The machine's physical memory [bytes], or None where the system does not say."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return None


def check_fits(nbytes: float, *, what: str, option: str) -> None:
    """MemoryError naming the size, ``what`` needs it and the ``option`` that asked for it, where
    ``nbytes`` [bytes] exceeds the physical memory."""
    have = physical_memory_bytes()
    if have is not None and nbytes > have:
        raise MemoryError(f"{what} need about {nbytes / 2**30:.1f} GiB, more than this machine's "
                          f"{have / 2**30:.1f} GiB; ask for fewer ({option})")
