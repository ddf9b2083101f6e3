"""Tests of rfmitsuba.core.memory: NumPy temporaries come from glibc's heap, which keeps them when freed."""
import os
import platform
import subprocess
import sys

import pytest

#: a fresh process allocates a 4 MiB array and prints how many bytes glibc mapped for it apart from
#: its heap (``mallinfo2().hblkhd``): all of it with glibc's defaults (a new mapping, new pages
#: every time), none when freed memory is kept (the block comes from the heap and goes back to it)
_SCRIPT = """
import ctypes, numpy as np
from rfmitsuba.core.memory import keep_freed_memory

class Info(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                "fsmblks", "uordblks", "fordblks", "keepcost")]

libc = ctypes.CDLL("libc.so.6")
libc.mallinfo2.restype = Info
print(keep_freed_memory())
before = libc.mallinfo2().hblkhd
a = np.ones(1 << 19)
print(libc.mallinfo2().hblkhd - before)
"""


def _mapped_bytes(keep: str) -> tuple[str, int]:
    env = dict(os.environ, RFMITSUBA_KEEP_MEMORY=keep)
    out = subprocess.run([sys.executable, "-c", _SCRIPT], env=env, capture_output=True, text=True, check=True)
    applied, mapped = out.stdout.split()
    return applied, int(mapped)


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc's malloc settings")
def test_freed_memory_is_reused():
    applied, mapped = _mapped_bytes("1")
    assert applied == "True" and mapped == 0
    applied, mapped = _mapped_bytes("0")                # glibc's defaults: a mapping of its own
    assert applied == "False" and mapped >= 1 << 22


def test_applies_once_and_says_so(monkeypatch):
    from rfmitsuba.core import memory

    monkeypatch.setattr(memory, "_applied", None)
    monkeypatch.setenv("RFMITSUBA_KEEP_MEMORY", "0")
    assert memory.keep_freed_memory() is False
    monkeypatch.setenv("RFMITSUBA_KEEP_MEMORY", "1")
    assert memory.keep_freed_memory() is False          # decided once per process
