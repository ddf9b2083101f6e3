"""Tests of rfmitsuba.core.memory: freed NumPy temporaries are reused, not faulted in again."""
import os
import platform
import subprocess
import sys

import pytest

#: a fresh process allocates, touches and frees a 4 MiB array, then does it again, and prints the
#: minor page faults of the second time (1024 pages of 4 KiB when the memory is new)
_SCRIPT = """
import resource, numpy as np
from rfmitsuba.core.memory import keep_freed_memory
print(keep_freed_memory())
a = np.ones(1 << 19); del a
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
b = np.ones(1 << 19); del b
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _second_allocation_faults(keep: str) -> tuple[str, int]:
    env = dict(os.environ, RFMITSUBA_KEEP_MEMORY=keep)
    out = subprocess.run([sys.executable, "-c", _SCRIPT], env=env, capture_output=True, text=True, check=True)
    applied, faults = out.stdout.split()
    return applied, int(faults)


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc's malloc settings")
def test_freed_memory_is_reused():
    applied, faults = _second_allocation_faults("1")
    assert applied == "True" and faults < 100
    applied, faults = _second_allocation_faults("0")    # glibc's defaults: new pages again
    assert applied == "False" and faults > 500


def test_applies_once_and_says_so(monkeypatch):
    from rfmitsuba.core import memory

    monkeypatch.setattr(memory, "_applied", None)
    monkeypatch.setenv("RFMITSUBA_KEEP_MEMORY", "0")
    assert memory.keep_freed_memory() is False
    monkeypatch.setenv("RFMITSUBA_KEEP_MEMORY", "1")
    assert memory.keep_freed_memory() is False          # decided once per process
