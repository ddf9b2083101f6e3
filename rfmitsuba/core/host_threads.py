"""Host work beside Dr.Jit's thread pool: NumPy products run inside a custom AD op on the LLVM
backend (the EM network's MLPs, :mod:`rfmitsuba.models.nn`; the Bartlett read-out,
:mod:`rfmitsuba.rf.bartlett_host`).

Such work is cut into a fixed number of *lanes* (contiguous ranges, each with its own partial
sums, added in lane order), so its bits do not depend on how many threads ran the lanes; lane
0 runs on the calling thread and the others on :func:`lane_pool`'s. While the lanes run, the
host's BLAS is held to one thread per lane and Dr.Jit's pool is cut to one thread
(:func:`host_threads`): both would otherwise compete with the lanes for the same cores. Scratch
arrays come from a :class:`Buffers` free list instead of fresh memory.
"""
from __future__ import annotations

import contextlib
import threading

import numpy as np

_BLAS = None
_POOL = None

#: threads of :func:`lane_pool` (lane 0 runs on the caller's thread)
POOL_THREADS = 1


def one_blas_thread():
    """A context in which the host's BLAS runs on one thread. Its own threads would compete with
    Dr.Jit's pool for the same cores: a splat step under load 5 took 1.4-1.8 s with BLAS's
    threads against 0.46 s with one (10 000 Gaussians, batch 4)."""
    global _BLAS
    if _BLAS is None:
        from threadpoolctl import ThreadpoolController

        _BLAS = ThreadpoolController()
    return _BLAS.limit(limits=1, user_api="blas")


@contextlib.contextmanager
def host_threads(threads: int):
    """A context for host work on ``threads`` threads: the host's BLAS on one thread each
    (:func:`one_blas_thread`) and, when ``threads > 1``, Dr.Jit's pool cut to one thread
    until the context ends (its count is restored). Dr.Jit's idle workers spin for a while
    before they sleep and would hold the cores the host threads need: the head's backward of a
    splat step (10 000 Gaussians, batch 4, 45 x 180) took 19.6 ms on two host threads beside
    Dr.Jit's two, 11.7 ms with Dr.Jit cut to one, 19.2 ms on one host thread (the whole step
    51-54 ms against 65-68 ms). Call it only where no kernel is running (after the inputs were
    read back)."""
    import drjit as dr

    with one_blas_thread():
        if threads <= 1:
            yield
            return
        before = dr.thread_count()
        dr.set_thread_count(1)
        try:
            yield
        finally:
            dr.set_thread_count(before)


def lane_pool():
    """The threads that run lanes 1.. of host work (lane 0 runs on the caller's)."""
    global _POOL
    if _POOL is None:
        from concurrent.futures import ThreadPoolExecutor

        _POOL = ThreadPoolExecutor(max_workers=POOL_THREADS, thread_name_prefix="rfmitsuba-host")
    return _POOL


def run_lanes(fn, lanes: int, *, threads: int) -> list:
    """``fn(k)`` for lanes ``k = 0 .. lanes - 1``: all on the calling thread when ``threads <= 1``,
    else lanes 1.. on :func:`lane_pool`'s threads beside lane 0 on this one. Returns their
    results in lane order."""
    if threads <= 1 or lanes <= 1:
        return [fn(k) for k in range(lanes)]
    pool = lane_pool()
    futures = [pool.submit(fn, k) for k in range(1, lanes)]
    first = fn(0)
    return [first] + [f.result() for f in futures]


class Buffers:
    """Host arrays kept for reuse, by shape and dtype, so a training step does not write into
    fresh memory: a first write to a fresh page faults, and two host threads faulting at once
    wait for each other. The EM network's host work in a splat step (10 000 Gaussians, batch 4,
    two host threads) took 7.4 ms forward and 12.1 ms backward with new arrays, 5.8 and 11.6 ms
    with kept ones. Thread-safe; at most :attr:`KEEP` arrays of one kind are kept (a backward
    pass on two lanes takes six scratch arrays of one shape)."""

    KEEP = 8

    def __init__(self):
        self._free: dict = {}
        self._lock = threading.Lock()

    def take(self, shape: tuple, dtype=np.float32) -> np.ndarray:
        """An uninitialised C-contiguous array of ``shape`` (a kept one where there is one)."""
        key = (tuple(int(s) for s in shape), np.dtype(dtype).str)
        with self._lock:
            free = self._free.get(key)
            if free:
                return free.pop()
        return np.empty(key[0], dtype)

    def give(self, arrays: list) -> None:
        """Hand arrays back (nobody may use them afterwards)."""
        with self._lock:
            for a in arrays:
                free = self._free.setdefault((a.shape, a.dtype.str), [])
                if len(free) < self.KEEP:
                    free.append(a)
