"""Per-image results that depend on the data alone (the floors of an evaluation), cached on disk.

The floors of :func:`rfmitsuba.eval.dynamic_static.evaluate` (nearest neighbour, IDW-3, mean
image, and the empty room's own PAS) depend on the dataset, its split and the training noise,
never on the model. A reproduction evaluates every job of a dataset against the same floors;
computing them in every job took a full-size bedroom job's evaluation to 46 s, against 10 s
with them cached (most of it reading the 20 000 training PAS with a person that the
nearest-neighbour lookup searches).

One entry is one ``.npz`` file (written atomically, read without pickle) named by the sha256
of its key; the key is stored inside and compared on reading, so a stale, foreign or damaged
file is computed again and replaced. The key holds the dataset's
:meth:`~rfmitsuba.data.store.Dataset.fingerprint`, so a regenerated dataset never reuses the
floors of the old one, and :data:`FLOORS_VERSION`, raised whenever the floors' arithmetic changes.
"""
from __future__ import annotations

import hashlib
import json
import zipfile
from pathlib import Path
from typing import Callable

import numpy as np

from ..core.atomic import write_npz

#: raise when the floors' computation changes (cached entries of other versions are recomputed)
FLOORS_VERSION = 1

_KEY = "__key__"


def _key_text(key: dict) -> str:
    return json.dumps({**key, "floors_version": FLOORS_VERSION}, sort_keys=True)


def entry_path(folder: str | Path, key: dict) -> Path:
    """The file of the entry ``key`` (a JSON-able dict) in ``folder``."""
    return Path(folder) / (hashlib.sha256(_key_text(key).encode()).hexdigest()[:32] + ".npz")


def load(folder: str | Path, key: dict, *, length: int) -> dict[str, np.ndarray] | None:
    """The arrays of entry ``key``, each of first dimension ``length``; None when the entry is
    missing, unreadable, of another key or of another length."""
    f = entry_path(folder, key)
    if not f.is_file():
        return None
    try:
        with np.load(f, allow_pickle=False) as z:
            arrays = {k: np.asarray(z[k]) for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):
        return None
    if str(arrays.pop(_KEY, "")) != _key_text(key):
        return None
    if not arrays or any(a.ndim < 1 or len(a) != length for a in arrays.values()):
        return None
    return arrays


def cached(folder: str | Path | None, key: dict, compute: Callable[[], dict[str, np.ndarray]], *,
           length: int) -> dict[str, np.ndarray]:
    """``compute()`` (name -> array [length, ...]), read from ``folder`` when an entry of ``key``
    is there, else computed and written there; ``folder`` None: always computed, nothing written."""
    if folder is None:
        return compute()
    hit = load(folder, key, length=length)
    if hit is not None:
        return hit
    arrays = {k: np.asarray(v) for k, v in compute().items()}
    Path(folder).mkdir(parents=True, exist_ok=True)
    write_npz(entry_path(folder, key), {**arrays, _KEY: np.array(_key_text(key))})
    return arrays
