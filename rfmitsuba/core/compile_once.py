"""Build something expensive once, on first use, from any thread: the fused Numba loops of
:mod:`rfmitsuba.rf.bartlett_loops` and :mod:`rfmitsuba.models.nn.host_loops`."""
from __future__ import annotations

import threading
from typing import Callable


class CompiledOnce:
    """``make()`` called once, on the first call of this object (host lanes may ask at the same
    time: one of them builds it, the others wait); its result, or None where ``make`` gives None
    (Numba absent: the callers use their NumPy twins)."""

    def __init__(self, make: Callable[[], object]):
        self._make = make
        self._value = None
        self._done = False
        self._lock = threading.Lock()

    def __call__(self):
        if not self._done:
            with self._lock:
                if not self._done:
                    self._value, self._done = self._make(), True
        return self._value
