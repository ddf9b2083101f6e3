"""Atomic file writes: write a temporary file beside the target, then rename it over the target.

A reader (or a resumed run) sees either the old file or the new one, never half of one. The
temporary name carries the process id, so two processes (Dask workers) writing the same file
never write into one temporary file; the last rename wins.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically; returns the path."""
    path = Path(path)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    tmp.replace(path)
    return path


def write_json(path: str | Path, obj: Any, *, indent: int = 1, end: str = "", **dumps_kw) -> Path:
    """Write ``obj`` as JSON atomically (``json.dumps`` options pass through; ``end`` is appended)."""
    return write_text(path, json.dumps(obj, indent=indent, **dumps_kw) + end)


def numpy_default(o: Any):
    """``json.dumps(default=...)`` for NumPy values: scalars to numbers, arrays to lists."""
    import numpy as np

    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_npz(path: str | Path, arrays: dict) -> Path:
    """Write NumPy ``arrays`` (name -> array; no object arrays) as an ``.npz`` atomically."""
    import numpy as np

    path = Path(path)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp.npz")
    np.savez(tmp, **arrays)
    tmp.replace(path)
    return path
