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


def write_json_with_numpy(path: str | Path, obj: Any) -> Path:
    """Write results that hold NumPy values (as numbers and lists) and may hold NaN (a score that
    could not be computed) as JSON atomically."""
    return write_json(path, obj, allow_nan=True, default=numpy_default)


def finite_or_null(obj: Any) -> Any:
    """``obj`` (dicts, lists and tuples of values) with every non-finite number (NaN, infinity)
    replaced by None, so its JSON is standard JSON (``null``) that any reader accepts."""
    import math

    if isinstance(obj, dict):
        return {k: finite_or_null(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_null(v) for v in obj]
    if isinstance(obj, float) or type(obj).__name__ in ("float32", "float64", "float16"):
        return float(obj) if math.isfinite(float(obj)) else None
    return obj


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
