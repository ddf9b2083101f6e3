"""Keep freed memory in the process: glibc's malloc settings for long runs of NumPy work.

A job allocates and frees the same temporaries over and over (an SSIM's dozen 90 x 360 float64
images per pair, a batch's PAS, a state's images). By default glibc serves blocks over 128 KiB
(raising that to at most 32 MiB as it sees them freed) with fresh ``mmap`` pages and gives the
top of its heap back to the system, so the next temporary is new memory again, which the kernel
must zero on first touch. On a 2-core virtual machine where it was measured, that zeroing ran
at under 1 GB/s: a sampled reproduction worker spent 27% of its CPU time in the kernel, most of it
in ``clear_page_erms``, and 600 SSIMs took 2.5-3.7 s against 1.0-1.2 s with freed memory kept.

:func:`keep_freed_memory` sets, for the whole process: blocks up to 32 MiB (glibc's largest
``mmap`` threshold) come from the heap, whose top is given back only beyond 1 GiB free, and the
heap grows 64 MiB at a time. The price is a larger resident size after a peak (at most the
trim threshold more). The CLI and every Dask task call it; a notebook may call it too.
``RFMITSUBA_KEEP_MEMORY=0`` leaves glibc's defaults. Elsewhere than glibc it does nothing.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import platform

#: mallopt parameters (glibc's malloc.h)
_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD = -1, -2, -3
#: blocks up to this many bytes come from the heap (glibc refuses more than 32 MiB on 64-bit)
MMAP_THRESHOLD_BYTES = 32 << 20
#: free memory at the heap's top kept up to this many bytes
TRIM_THRESHOLD_BYTES = 1 << 30
#: extra bytes the heap grows by each time
TOP_PAD_BYTES = 64 << 20

_applied: bool | None = None


def keep_freed_memory() -> bool:
    """Apply the settings of the module docstring once per process.

    Returns:
        True where glibc took them (now or earlier), False where they do not apply (not glibc,
        ``RFMITSUBA_KEEP_MEMORY=0``, or glibc refused).
    """
    global _applied
    if _applied is not None:
        return _applied
    _applied = False
    if os.environ.get("RFMITSUBA_KEEP_MEMORY", "1").strip() == "0" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    _applied = all(mallopt(param, value) == 1 for param, value in (
        (_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES), (_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES),
        (_M_TOP_PAD, TOP_PAD_BYTES)))
    return _applied
