"""Training images of a dataset state made once and kept beside it: the min-max normalised
``d x d`` block means of every antenna position's PAS.

Every job of a comparison or reproduction that trains on a walk dataset read the same 20 000
full-resolution PAS (2.6 GB) from disk and block-averaged and normalised them again: a full-size
Ours job spent 22 s of its 55 s outside its training steps doing so, most of it waiting for the
disk (docs/lab-notes/speed.md). The images at ``d = 2`` are a quarter of that size and
need no arithmetic.

One entry is one state at one block size, in the dataset's own folder::

    DATASET/cache/pas_d2/00003.npy    float32 [A, 90/d, 360/d], the images of state 3 (memory-mapped)
    DATASET/cache/pas_d2/00003.json   what they were made from (the digest of chunks/00003/chunk.json,
                                      d, the format version, the shape) and which raw PAS were finite

Each is written atomically on first use, so two processes making the same entry (Dask workers)
both leave a whole file. An entry whose chunk has changed (a regenerated state), of another
version or shape, or that cannot be read is made again. A dataset folder that cannot be written
to is read as before, without a cache. The images are computed by the functions
:func:`rfmitsuba.data.views.normalised_pas` uses (block means, then min-max), whose arithmetic is
image by image, so a cached read is bit-identical to an uncached one. Only dataset folders
(:class:`~rfmitsuba.data.store.Dataset`) have chunks to key an entry by: a NeRF2 folder is read
without a cache.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from ..core.atomic import write_json
from ..core.errors import DatasetError
from ..rf.bartlett_ref import normalize as minmax
from ..rf.grid import PAS_SHAPE
from .store import chunk_name
from .views import downsample

#: raise when the cached images' arithmetic changes (entries of other versions are made again)
PAS_CACHE_VERSION = 1


def entry_paths(dataset_path: str | Path, state: int, d: int) -> tuple[Path, Path]:
    """(images ``.npy``, key ``.json``) of state ``state`` at block size ``d``."""
    folder = Path(dataset_path) / "cache" / f"pas_d{int(d)}"
    name = chunk_name(state)   # the state's chunk folder's name
    return folder / f"{name}.npy", folder / f"{name}.json"


def _key(ds, state: int, d: int) -> dict:
    f = Path(ds.path) / "chunks" / chunk_name(state) / "chunk.json"
    try:
        digest = hashlib.sha256(f.read_bytes()).hexdigest()
    except OSError as e:
        raise DatasetError(f"chunk {f.parent}: chunk.json unreadable ({e})") from None
    return {"chunk_json_sha256": digest, "d": int(d), "version": PAS_CACHE_VERSION,
            "shape": [int(ds.num_antennas), PAS_SHAPE[0] // d, PAS_SHAPE[1] // d]}


def _load(npy: Path, meta: Path, key: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """(images memmap, finite bool [A]) of an entry made from ``key``; None if missing or stale."""
    try:
        stored = json.loads(meta.read_text())
        if {k: stored.get(k) for k in key} != key:
            return None
        images = np.load(npy, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError, EOFError):
        return None
    finite = np.asarray(stored.get("finite", []), bool)
    if images.dtype != np.float32 or list(images.shape) != key["shape"] or finite.shape != (key["shape"][0],):
        return None
    return images, finite


def _make(ds, state: int, d: int) -> tuple[np.ndarray, np.ndarray]:
    """The images and finite flags of one state, computed: float32 [A, H/d, W/d], bool [A]."""
    raw = ds.pas(state)
    images = np.empty((ds.num_antennas, PAS_SHAPE[0] // d, PAS_SHAPE[1] // d), np.float32)
    finite = np.empty(ds.num_antennas, bool)
    step = 256
    for a0 in range(0, ds.num_antennas, step):
        x = np.asarray(raw[a0:a0 + step], np.float32)
        finite[a0:a0 + len(x)] = np.isfinite(x).all(axis=(1, 2))
        images[a0:a0 + len(x)] = minmax(downsample(x, d))
    return images, finite


def state_images(ds, state: int, *, d: int) -> tuple[np.ndarray, np.ndarray]:
    """The normalised ``d x d`` block means of every antenna of dataset ``ds``'s state ``state``
    (float32 [A, 90/d, 360/d], read-only memmap where cached) and which of the raw PAS were
    finite (bool [A]); made and written on first use, read after.

    Raises:
        DatasetError: the state's chunk cannot be read.
    """
    npy, meta = entry_paths(ds.path, state, d)
    key = _key(ds, state, d)
    hit = _load(npy, meta, key)
    if hit is not None:
        return hit
    images, finite = _make(ds, state, d)
    try:
        npy.parent.mkdir(parents=True, exist_ok=True)
        tmp = npy.with_name(f"{npy.name}.{os.getpid()}.tmp.npy")
        np.save(tmp, images, allow_pickle=False)
        tmp.replace(npy)
        write_json(meta, {**key, "finite": finite.tolist()})
    except OSError:   # a folder we may not write to: the images as computed, no cache
        return images, finite
    return images, finite
