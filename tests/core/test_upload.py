"""Tests of rfmitsuba.core.upload: host arrays handed to Dr.Jit in 64-byte-aligned memory."""
from __future__ import annotations

import numpy as np
import pytest


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.uint32])
@pytest.mark.parametrize("offset", [0, 1, 3, 16, 17])
def test_aligned_is_an_aligned_copy(dtype, offset):
    from rfmitsuba.core.upload import ALIGN, aligned

    base = np.arange(200, dtype=dtype)
    src = base[offset:offset + 60].reshape(6, 10)[:, ::2]      # misaligned and strided
    out = aligned(src)
    assert out.ctypes.data % ALIGN == 0 and out.flags.c_contiguous
    assert out.dtype == src.dtype and out.shape == src.shape
    np.testing.assert_array_equal(out, src)
    base[:] = 0                                                 # a copy, not a view
    assert out.any()


def test_upload_keeps_its_values_after_the_host_array_changes(variant):
    """Dr.Jit borrows (and reads lazily) the memory of an array it is given; an upload is a copy."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.core.upload import upload

    host = np.arange(40, dtype=np.float64)
    jit = upload(B.Float, host[1:33])
    host[:] = -1.0
    np.testing.assert_array_equal(jit.numpy(), np.arange(1, 33, dtype=np.float32))
    assert upload(B.UInt32, [3, 4], dtype=np.uint32).numpy().tolist() == [3, 4]


@pytest.mark.parametrize("rows", [0, 1, 15, 16, 37])
def test_upload_columns_gives_every_column(variant, rows):
    from rfmitsuba.core import backend as B
    from rfmitsuba.core.upload import upload_columns

    values = np.random.default_rng(rows).normal(size=(rows, 5)).astype(np.float32)
    cols = upload_columns(B.Float, values)
    assert len(cols) == 5
    for k, c in enumerate(cols):
        np.testing.assert_array_equal(c.numpy(), values[:, k])


def test_upload_columns_needs_a_matrix(variant):
    from rfmitsuba.core import backend as B
    from rfmitsuba.core.upload import upload_columns

    with pytest.raises(ValueError, match=r"\[M, D\].*\(4,\)"):
        upload_columns(B.Float, np.zeros(4, np.float32))


def _misses(arrays, constant: float) -> list[int]:
    """Per host array: kernels compiled (not found in the in-memory or on-disk cache) to evaluate
    ``x * 3 + constant`` (the constant is part of the kernel)."""
    import drjit as dr

    misses = []
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        for x in arrays:
            dr.eval(x * 3.0 + constant)
            misses.append(sum(1 for k in dr.kernel_history()
                              if k["type"] == dr.KernelType.JIT and not k["cache_hit"]))
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    return misses


def test_alignment_of_the_host_memory_decides_the_kernel(variant):
    """Why the module exists: on LLVM a borrowed array's alignment is part of the kernel, so the
    same arithmetic on differently aligned host memory compiles again; uploads compile once.
    Offsets are float32 elements: 0 and 16 are 64-byte aligned in ``buf``, 1, 2 and 17 are not."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.core.upload import upload

    if B.is_cuda():
        pytest.skip("a CUDA upload is a copy into device memory")
    buf = np.empty(4096 + 64, np.float32)
    start = (-buf.ctypes.data % 64) // 4
    views = [buf[start + off:start + off + 1000] for off in (0, 16, 1, 2, 17)]
    for v in views:
        v[:] = np.arange(1000)
    constant = float(np.random.default_rng().uniform(1, 2))   # a kernel no earlier run compiled
    borrowed = _misses([B.Float(v) for v in views], constant)
    assert borrowed[0] == 1 and borrowed[1] == 0 and borrowed[2] == 1 and borrowed[3:] == [0, 0]
    uploaded = _misses([upload(B.Float, v) for v in views], constant)
    assert uploaded == [0] * 5


@pytest.mark.parametrize("rows", [0, 1, 15, 37])
@pytest.mark.parametrize("cols", [1, 3, 64])
def test_upload_rows_gives_every_column(variant, rows, cols):
    """Columns gathered from the rows of one buffer: the same values as the host array's columns,
    from an aligned array (borrowed) or from a strided, misaligned one (copied first)."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.core.upload import empty_aligned, is_aligned, upload_rows

    values = np.random.default_rng(rows * cols).normal(size=(rows, cols)).astype(np.float32)
    kept = empty_aligned(values.shape)
    kept[...] = values
    assert is_aligned(kept) or rows == 0      # NumPy may move an empty array's pointer
    strided = np.zeros((rows, 2 * cols + 1), np.float32)[:, 1::2]
    strided[...] = values
    assert not is_aligned(strided) or rows == 0
    for host in (kept, strided):
        out = upload_rows(B.Float, host)
        assert len(out) == cols
        for k, c in enumerate(out):
            np.testing.assert_array_equal(c.numpy(), values[:, k])


def test_upload_rows_borrows_an_aligned_array(variant):
    """An aligned array is read where it lies (LLVM: no copy), so the caller must not write it
    afterwards; a misaligned one is copied first."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.core.upload import empty_aligned, upload_rows

    if B.is_cuda():
        pytest.skip("a CUDA upload is a copy into device memory")
    host = empty_aligned((8, 2))
    host[...] = 1.0
    cols = upload_rows(B.Float, host)
    host[3, 1] = 5.0
    assert cols[1].numpy()[3] == 5.0 and cols[0].numpy()[3] == 1.0


def test_upload_rows_needs_a_matrix(variant):
    from rfmitsuba.core import backend as B
    from rfmitsuba.core.upload import upload_rows

    with pytest.raises(ValueError, match=r"\[M, D\].*\(4,\)"):
        upload_rows(B.Float, np.zeros(4, np.float32))


def test_zeros_aligned():
    from rfmitsuba.core.upload import ALIGN, zeros_aligned

    z = zeros_aligned((7, 3), np.float64)
    assert z.ctypes.data % ALIGN == 0 and z.dtype == np.float64 and z.shape == (7, 3) and not z.any()
