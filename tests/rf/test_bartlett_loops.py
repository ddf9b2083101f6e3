"""Tests of rfmitsuba.rf.bartlett_loops: each fused loop against its NumPy twin, bit for bit."""
from __future__ import annotations

import numpy as np
import pytest

from rfmitsuba.rf import bartlett_loops as L


def _arrays(rng, rows=5, cols=333):
    yr, yi = (rng.normal(size=(rows, cols)).astype(np.float32) for _ in range(2))
    yr[0, :2] = yi[0, :2] = 0.0                  # a zero amplitude: the adjoint's floor
    return yr, yi


def _same(a, b):
    assert np.array_equal(np.asarray(a).view(np.uint32), np.asarray(b).view(np.uint32))


@pytest.mark.parametrize("a, b", [(0, None), (64, 200)])
def test_amplitude_matches_its_twin_bit_for_bit(a, b):
    yr, yi = _arrays(np.random.default_rng(1))
    out = np.full_like(yr, -1.0)
    L.amplitude(yr, yi, out, a, b)
    stop = yr.shape[1] if b is None else b
    _same(out[:, a:stop], L.amplitude_numpy(yr[:, a:stop], yi[:, a:stop], np.empty((5, stop - a), np.float32)))
    assert (out[:, :a] == -1.0).all() and (out[:, stop:] == -1.0).all()    # only its columns
    np.testing.assert_allclose(out[:, a:stop], np.hypot(yr, yi)[:, a:stop], rtol=1e-6)


def test_normalized_matches_its_twin_and_counts_the_pixels_near_the_extremes():
    """Two column ranges (two lanes) give the twin's bits, and their counts of the pixels near
    each image's minimum and maximum add up to the twin's."""
    rng = np.random.default_rng(2)
    p = np.abs(rng.normal(size=(4, 300))).astype(np.float32)
    p[1, [7, 190]] = p[1].min()                  # ties at the minimum, one in each range
    p[2, 250] = np.nextafter(p[2].max(), np.float32(0))     # a close call at the maximum
    lo, hi = p.min(1), p.max(1)
    span = np.maximum(hi - lo, L.TINY)
    near_lo, near_hi = lo + np.float32(1e-6), hi - np.float32(1e-6)
    want, want_count = np.empty_like(p), np.zeros((4, 2), np.int64)
    L.normalized_numpy(p, lo, span, near_lo, near_hi, want, want_count)
    got, count = np.empty_like(p), np.zeros((4, 2), np.int64)
    for a, b in ((0, 150), (150, 300)):
        part = np.zeros((4, 2), np.int64)
        L.normalized(p, lo, span, near_lo, near_hi, got, part, a, b)
        count += part
    _same(got, want)
    assert np.array_equal(count, want_count)
    assert count[1, 0] == np.count_nonzero(p[1] == lo[1]) >= 2 and count[2, 1] == 2
    assert count[0, 0] == count[0, 1] == count[3, 0] == count[3, 1] == 1


def test_beam_grad_matches_its_twin_bit_for_bit():
    rng = np.random.default_rng(3)
    yr, yi = _arrays(rng)
    p = L.amplitude_numpy(yr, yi, np.empty_like(yr))
    g = rng.normal(size=p.shape).astype(np.float32)
    inv = rng.uniform(0.5, 2.0, size=5).astype(np.float32)
    a, b = 33, 301
    got = [np.empty((5, b - a), np.float32) for _ in range(2)]
    want = [np.empty((5, b - a), np.float32) for _ in range(2)]
    L.beam_grad(g, p, yr, yi, inv, *got, a, b)
    L.beam_grad_numpy(g[:, a:b], p[:, a:b], yr[:, a:b], yi[:, a:b], inv, *want)
    for x, y in zip(got, want):
        _same(x, y)
        assert np.isfinite(x).all()


def test_the_loops_are_compiled_where_numba_is_installed():
    pytest.importorskip("numba")
    assert L.compiled()


def test_image_sums_match_their_twin_to_float32_rounding():
    rng = np.random.default_rng(4)
    g, pn = (rng.normal(size=(3, 1000)).astype(np.float32) for _ in range(2))
    got = L.image_sums(g, pn, 100, 900)
    want = L.image_sums_numpy(g[:, 100:900], pn[:, 100:900])
    exact = ((g[:, 100:900].astype(np.float64) * pn[:, 100:900]).sum(1), g[:, 100:900].astype(np.float64).sum(1))
    for x, y, e in zip(got, want, exact):
        assert x.dtype == np.float32 and x.shape == (3,)
        np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-4)
        np.testing.assert_allclose(x, e, rtol=1e-5, atol=1e-4)
