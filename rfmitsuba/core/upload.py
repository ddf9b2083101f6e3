"""Host arrays handed to Dr.Jit in 64-byte-aligned memory.

On the LLVM backend Dr.Jit borrows a NumPy array's memory instead of copying it, and whether
that memory is 64-byte aligned is written into every kernel that reads it (``align 64`` or
``align 1`` loads): the same kernel on a differently aligned upload is another kernel, compiled
again. NumPy promises 16-byte alignment only, so a step that uploads fresh arrays (a batch's
target images, the host products of :class:`rfmitsuba.models.nn.MLP`) met a new combination of
alignments almost every step: the splat field's traced Stage-1 step (10 000 Gaussians, batch 4,
45 x 180) compiled 17 kernels in 20 steps, 25 ms each (docs/lab-notes/speed.md). A recorded step (:mod:`rfmitsuba.train.frozen_step`) is valid only for the alignments it
was recorded with, for the same reason.

Every upload in a training or rendering step goes through :func:`upload` (the columns of a
matrix: :func:`upload_columns`, one copy for all of them; :func:`aligned` for arrays kept on the
host). A borrowed array is also read lazily, when its kernel runs: a
copy made here cannot be changed behind Dr.Jit's back by later writes to the caller's array.
On CUDA an upload is a copy into the device's own memory, so this costs one host copy only.
"""
from __future__ import annotations

import numpy as np

#: the alignment [bytes] of every host buffer this module hands to Dr.Jit
ALIGN = 64


def aligned(values) -> np.ndarray:
    """A C-contiguous copy of ``values`` (any array-like, any strides) whose first byte is
    :data:`ALIGN`-byte aligned; same shape and dtype. Always a copy, never a view of
    ``values``."""
    values = np.asarray(values)
    out = empty_aligned(values.shape, values.dtype)
    out[...] = values
    return out


def upload(array_type, values, *, dtype=np.float32):
    """``array_type`` (a Dr.Jit type such as ``B.Float``, ``B.UInt32`` or ``B.TensorXf``) holding
    an :func:`aligned` copy of ``values`` converted to ``dtype`` (float32 by default)."""
    return array_type(aligned(np.asarray(values, dtype=dtype)))


def empty_aligned(shape, dtype=np.float32) -> np.ndarray:
    """An uninitialised C-contiguous array whose first byte is :data:`ALIGN`-byte aligned."""
    dtype = np.dtype(dtype)
    count = int(np.prod(shape, dtype=np.int64))
    buf = np.empty(count * dtype.itemsize + ALIGN, np.uint8)
    start = -buf.ctypes.data % ALIGN
    return buf[start:start + count * dtype.itemsize].view(dtype).reshape(shape)


def zeros_aligned(shape, dtype=np.float32) -> np.ndarray:
    """:func:`empty_aligned`, filled with zeros."""
    out = empty_aligned(shape, dtype)
    out.fill(0)
    return out


def is_aligned(values: np.ndarray) -> bool:
    """Whether ``values`` is C-contiguous and its first byte :data:`ALIGN`-byte aligned (what
    :func:`upload_rows` hands to Dr.Jit without a copy)."""
    return bool(values.flags.c_contiguous) and values.ctypes.data % ALIGN == 0


def _matrix(values, what: str) -> np.ndarray:
    """``values`` as a NumPy array [M, D]; ValueError naming ``what`` otherwise."""
    values = np.asarray(values)
    if values.ndim != 2:
        raise ValueError(f"{what}: expected a host array [M, D], got shape {values.shape}")
    return values


def upload_rows(array_type, values) -> list:
    """The D columns of a host array [M, D] as D ``array_type`` arrays of width M that gather
    from one flat buffer holding ``values`` row by row (element ``m * D + k`` of the buffer).

    Where ``values`` is already :func:`is_aligned` (the host products of
    :class:`rfmitsuba.models.nn.MLP` write into such arrays) Dr.Jit borrows its memory: no copy
    and no transpose on the host; the columns are lazy gathers that the kernels reading them
    compute, at a stride of D elements. The caller must not write ``values`` afterwards.
    :func:`upload_columns` instead copies into one contiguous array per column: a [10 000, 64]
    array took 0.72 ms that way against 0.065 ms here (the call alone, warm caches); the EM
    network's uploads in a splat training step 3.0 against 0.9 ms per step.

    Raises:
        ValueError: ``values`` is not two-dimensional.
    """
    import drjit as dr

    values = _matrix(values, "upload_rows")
    m, d = values.shape
    if m == 0:
        return [array_type(np.zeros(0, values.dtype)) for _ in range(d)]
    if not is_aligned(values):
        values = aligned(values)
    flat = array_type(values.reshape(-1))
    if d == 1:
        return [flat]
    index_type = dr.uint32_array_t(array_type)
    rows = dr.arange(index_type, m) * d
    return [dr.gather(array_type, flat, rows + k) for k in range(d)]


def upload_columns(array_type, values) -> list:
    """The D columns of a host array [M, D] as D ``array_type`` arrays of width M, read from one
    :data:`ALIGN`-aligned buffer (transposed, each row padded to a multiple of :data:`ALIGN`
    bytes): one copy for all columns, and every column's first byte aligned.

    Raises:
        ValueError: ``values`` is not two-dimensional.
    """
    values = _matrix(values, "upload_columns")
    m, d = values.shape
    per_row = max(1, ALIGN // values.itemsize)
    buf = empty_aligned((d, -(-m // per_row) * per_row), values.dtype)
    buf[:, :m] = values.T
    return [array_type(buf[k, :m]) for k in range(d)]
