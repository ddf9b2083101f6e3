"""Tests of rfmitsuba.models.nn.host_loops: each fused loop against its NumPy twin."""
from __future__ import annotations

import numpy as np
import pytest

from rfmitsuba.models.nn import host_loops as H


def _case(rng, rows=37, cols=16):
    z = rng.normal(size=(rows, cols)).astype(np.float32)
    z[0, :4] = [0.0, -0.0, 1e-30, -1e-30]        # the sign edge cases of the derivative
    return z, rng.normal(size=cols).astype(np.float32)


def test_add_leaky_matches_its_twin_bit_for_bit():
    z, row = _case(np.random.default_rng(1))
    want = H.add_leaky_numpy(z, row, np.empty_like(z))
    got = H.add_leaky(z, row, np.empty_like(z))
    assert np.array_equal(got.view(np.uint32), want.view(np.uint32))
    ref = z.astype(np.float64) + row
    np.testing.assert_allclose(got, np.where(ref > 0, ref, 0.01 * ref), rtol=1e-6, atol=1e-7)
    inplace = z.copy()
    assert H.add_leaky(inplace, row, inplace) is inplace and np.array_equal(inplace, want)


@pytest.mark.parametrize("with_sum, with_acc", [(False, False), (True, False), (False, True), (True, True)])
def test_leaky_grad_matches_its_twin(with_sum, with_acc):
    """The gradient bits are the twin's; the column sums (added row by row, a product in the
    twin) and the accumulated input gradient agree to float32 rounding."""
    rng = np.random.default_rng(2)
    h, _ = _case(rng)
    d = rng.normal(size=h.shape).astype(np.float32)
    outs = []
    for fn in (H.leaky_grad_numpy, H.leaky_grad):
        dd = d.copy()
        colsum = np.full(h.shape[1], 0.5, np.float32) if with_sum else None
        acc = np.full(h.shape, -1.0, np.float32) if with_acc else None
        assert fn(dd, h, colsum, acc) is dd
        outs.append((dd, colsum, acc))
    (d0, s0, a0), (d1, s1, a1) = outs
    assert np.array_equal(d0, d1)
    np.testing.assert_array_equal(d1, d * np.where(h > 0, 1.0, 0.01).astype(np.float32))
    if with_sum:
        np.testing.assert_allclose(s1, s0, rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(s1, 0.5 + d1.astype(np.float64).sum(0), rtol=1e-5, atol=1e-5)
    if with_acc:
        assert np.array_equal(a1, a0)


def test_loops_take_strided_views():
    """A block of an F-ordered array (how host columns arrive) gives the contiguous result."""
    rng = np.random.default_rng(3)
    z, row = _case(rng, rows=20, cols=8)
    f = np.asfortranarray(z)
    assert np.array_equal(H.add_leaky(f[3:17], row, np.empty((14, 8), np.float32)),
                          H.add_leaky_numpy(z[3:17], row, np.empty((14, 8), np.float32)))


def test_the_loops_are_compiled_where_numba_is_installed():
    pytest.importorskip("numba")
    assert H.compiled()


def test_loops_compile_where_numba_cannot_cache(monkeypatch):
    """Numba refuses ``cache=True`` where no cache folder can be written (a read-only install):
    the loops are then compiled without a cache and give the same bits."""
    numba = pytest.importorskip("numba")
    real = numba.njit

    def njit(*args, **kw):
        if kw.get("cache"):
            raise RuntimeError("cannot cache function: no locator available")
        return real(*args, **kw)

    monkeypatch.setattr(numba, "njit", njit)
    add_leaky, leaky_grad = H._compile()
    z, row = _case(np.random.default_rng(4))
    assert np.array_equal(add_leaky(z, row, np.empty_like(z)), H.add_leaky_numpy(z, row, np.empty_like(z)))
    d = z.copy()
    assert np.array_equal(leaky_grad(d, z, None, None), H.leaky_grad_numpy(z.copy(), z))
