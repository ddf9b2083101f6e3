"""Large ``.npy`` files written past the page cache (``O_DIRECT``), hashed as they are written.

A dataset chunk is written once and read later, usually by another process. Written the plain
way, its bytes are first copied into fresh page-cache pages, and on this project's VMs the first
touch of a fresh page is the expensive part: writing a 117 MB state (900 PAS of 90 x 360) took
0.39-0.40 s in ``np.save`` + SHA-256 read-back + ``fsync``, of which 0.25 s was the copy into new
cache pages. :func:`save_npy` copies the file through one reused, page-aligned staging buffer
straight to the device, and hashes each piece on a second thread while the device takes it:
0.074-0.091 s for the same state, the SHA-256 included (0.13-0.14 s with the hash on the same
thread), and the data is on the device when it returns (the ``fsync`` that follows has nothing
left to write).

The cost of fresh pages moves to the first reader of the file (``np.load`` of that state from
the device: 0.23 s), which is often another process or another machine. File systems without
``O_DIRECT`` (tmpfs, some network file systems, other operating systems) get the same bytes
through a buffered write.
"""
from __future__ import annotations

import errno
import hashlib
import io
import mmap
import os
import threading
from pathlib import Path

import numpy as np

#: bytes per staging copy; a multiple of :data:`BLOCK`
STAGE_BYTES = 8 << 20
#: offset and length alignment of direct writes [bytes] (the largest logical block size in use)
BLOCK = 4096

_LOCAL = threading.local()


def _stage() -> memoryview:
    """This thread's page-aligned staging buffer (anonymous ``mmap``, reused across files)."""
    buf = getattr(_LOCAL, "stage", None)
    if buf is None:
        buf = _LOCAL.stage = mmap.mmap(-1, STAGE_BYTES)
    return memoryview(buf)


_HASHER = None


def _hasher():
    """The thread that hashes a direct write's pieces (hashlib lets go of the GIL)."""
    global _HASHER
    if _HASHER is None:
        from concurrent.futures import ThreadPoolExecutor

        _HASHER = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rfmitsuba-sha256")
    return _HASHER


def npy_header(shape: tuple, dtype, *, fortran_order: bool = False) -> bytes:
    """The ``.npy`` (format 1.0) header ``np.save`` writes before the data of an array of
    ``shape`` and ``dtype`` (stored in Fortran order where ``fortran_order``)."""
    out = io.BytesIO()
    np.lib.format.write_array_header_1_0(out, {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)),
                                               "fortran_order": bool(fortran_order), "shape": tuple(shape)})
    return out.getvalue()


def _write_all(fd: int, view: memoryview) -> None:
    done = 0
    while done < len(view):
        done += os.write(fd, view[done:])


def _pieces(header: bytes, blocks, stage: memoryview):
    """The file's bytes (``header``, then each byte view of ``blocks`` in turn) copied into
    ``stage`` piece by piece: yields the filled length of each piece (every piece but the last
    is full)."""
    fill = len(header)
    stage[:fill] = header
    for data in blocks:
        pos = 0
        while pos < len(data):
            n = min(len(stage) - fill, len(data) - pos)
            stage[fill:fill + n] = data[pos:pos + n]
            pos += n
            fill += n
            if fill == len(stage):
                yield fill
                fill = 0
    if fill:
        yield fill


def _save_direct(path: Path, header: bytes, blocks) -> str:
    stage = _stage()
    digest = hashlib.sha256()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_DIRECT, 0o644)
    offset, tail = 0, b""
    try:
        for fill in _pieces(header, blocks, stage):
            # the piece is hashed on another thread while this one waits for the device
            hashed = _hasher().submit(digest.update, stage[:fill])
            try:
                whole = fill - fill % BLOCK
                _write_all(fd, stage[:whole])
                offset += whole
                tail = bytes(stage[whole:fill])      # only the last piece can leave a part block
            finally:
                hashed.result()                  # before the staging buffer is filled again
    finally:
        os.close(fd)
    with open(path, "r+b") as fh:           # the last part block, buffered, then all of it durable
        if tail:
            fh.seek(offset)
            fh.write(tail)
            fh.flush()
        os.fsync(fh.fileno())
    return digest.hexdigest()


def _save_buffered(path: Path, header: bytes, blocks) -> str:
    digest = hashlib.sha256(header)
    with open(path, "wb") as fh:
        fh.write(header)
        for data in blocks:
            for start in range(0, len(data), STAGE_BYTES):
                piece = data[start:start + STAGE_BYTES]
                digest.update(piece)
                fh.write(piece)
        fh.flush()
        os.fsync(fh.fileno())
    return digest.hexdigest()


def _save(path: Path, header: bytes, blocks, *, direct: bool) -> str:
    """``blocks``: a callable that gives the data's byte views in order (called again when a
    direct write is refused before anything was written and the buffered one starts over)."""
    if direct and hasattr(os, "O_DIRECT"):
        try:
            return _save_direct(path, header, blocks())
        except OSError as e:             # no O_DIRECT here (tmpfs, some network file systems)
            if e.errno not in (errno.EINVAL, errno.EOPNOTSUPP, errno.ENOTSUP):
                raise
    return _save_buffered(path, header, blocks())


def save_npy(path: str | Path, array: np.ndarray, *, direct: bool = True) -> str:
    """Write ``array`` as the ``.npy`` file ``np.save(path, array)`` would (same bytes), on the
    device when this returns (``fsync``); returns the file's SHA-256 (hex).

    Args:
        array: any array without Python objects (a Fortran-ordered one is stored in Fortran
            order, any other in C order, as ``np.save`` does).
        direct: write past the page cache where the file system allows it (``O_DIRECT``);
            False, or a file system that refuses it: a buffered write.

    Raises:
        ValueError: an object array (``np.save`` would pickle it).
    """
    path = Path(path)
    array = np.asanyarray(array)
    if array.dtype.hasobject:
        raise ValueError(f"{path.name}: object arrays are not written (they would need pickle)")
    if not (array.flags.c_contiguous or array.flags.f_contiguous):
        array = array.copy(order="C")
    fortran = array.flags.f_contiguous and not array.flags.c_contiguous   # stored as such, as np.save does
    header = npy_header(array.shape, array.dtype, fortran_order=fortran)
    raw = array.T if fortran else array
    data = memoryview(raw.reshape(-1).view(np.uint8))
    return _save(path, header, lambda: [data], direct=direct)


def save_npy_blocks(path: str | Path, blocks, *, shape: tuple, dtype=np.float32, direct: bool = True) -> str:
    """Write the ``.npy`` file of a C-ordered array of ``shape`` and ``dtype`` from its leading-
    axis blocks, as :func:`save_npy` would write their concatenation, without ever holding it
    whole: a caller makes each block into one reused buffer while the previous one is written.

    Args:
        blocks: iterable of arrays [k, *shape[1:]] (any k; cast to ``dtype``, in order) whose k
            add up to ``shape[0]``; it is consumed once: a file system that refuses ``O_DIRECT``
            at the open gets a buffered write, one that refuses it at the first write an
            ``OSError`` (pass ``direct=False`` there).

    Returns:
        The file's SHA-256 (hex).

    Raises:
        ValueError: a block of another trailing shape, or blocks that do not add up to
            ``shape[0]`` (the file is then incomplete: write into a temporary name).
    """
    path = Path(path)
    shape = tuple(int(n) for n in shape)
    dtype = np.dtype(dtype)
    header = npy_header(shape, dtype)
    started = []

    def views():
        started.append(True)             # runs at the first block asked for
        rows = 0
        for block in blocks:
            block = np.ascontiguousarray(block, dtype=dtype)
            if block.shape[1:] != shape[1:]:
                raise ValueError(f"{path.name}: a block of shape {block.shape}, expected [k, {', '.join(map(str, shape[1:]))}]")
            rows += block.shape[0]
            if rows > shape[0]:
                raise ValueError(f"{path.name}: the blocks hold more than {shape[0]} rows")
            yield memoryview(block.reshape(-1).view(np.uint8))
        if rows != shape[0]:
            raise ValueError(f"{path.name}: the blocks hold {rows} rows, expected {shape[0]}")

    def fresh():
        if started:
            raise OSError(errno.EINVAL, f"{path.name}: this file system refused O_DIRECT after the first blocks "
                                        "were consumed; write it with direct=False")
        return views()

    return _save(path, header, fresh, direct=direct)
