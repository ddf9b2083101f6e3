"""Tests of rfmitsuba.models.nn.host_columns: host arrays behind uploads."""
from __future__ import annotations

import numpy as np
import pytest


def test_host_columns_read_kept_uploads_without_a_kernel(variant):
    """The hand-off between two host MLPs (trunk -> head forward, head -> trunk backward): columns
    of a recent kept upload give back the very host array, and no kernel runs; other columns are
    evaluated together and stacked; an empty list gives None."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.core.upload import empty_aligned
    from rfmitsuba.models.nn import host_columns

    if B.is_cuda():
        pytest.skip("the host products run on the LLVM backend only")
    host = empty_aligned((37, 5))
    host[...] = np.random.default_rng(5).normal(size=(37, 5))
    kept = host_columns.upload_kept(B.Float, host)
    lazy = [B.Float(np.arange(37, dtype=np.float32)) * float(k + 1) for k in range(3)]
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        got_kept, got_none = host_columns.host_columns([kept, []])
        ran = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
        got_lazy, = host_columns.host_columns([lazy])
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert got_kept is host and got_none is None and ran == []
    np.testing.assert_array_equal(got_lazy, np.arange(37, dtype=np.float32)[:, None] * np.arange(1, 4))
