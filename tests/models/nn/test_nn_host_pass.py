"""Tests of rfmitsuba.models.nn.host_pass: one MLP call on host arrays, against float64 NumPy."""
from __future__ import annotations

import numpy as np
import pytest


def _host_pass_case(rng, *, n: int, views: int, widths: tuple):
    """Random inputs, packed weights and layer table of a host MLP (row stride = fan-in + 3, so
    the packing's padding is exercised), and the outputs' gradients."""
    layers, size = [], 0
    for n_in, n_out in zip(widths[:-1], widths[1:]):
        st = n_in + 3
        layers.append((size, n_out, n_in, st, size + n_out * st))
        size += n_out * st + n_out
    w = rng.normal(0, 0.4, size).astype(np.float32)
    x = rng.normal(size=(n, widths[0])).astype(np.float32)
    y = rng.normal(size=(views, widths[0])).astype(np.float32) if views else None
    dz = rng.normal(size=((views or 1) * n, widths[-1])).astype(np.float32)
    return x, y, w, tuple(layers), dz


def _host_pass_reference(x, y, w, layers, dz):
    """The same MLP in float64 NumPy over all rows at once, and its gradients by hand:
    (out, gw, gx, gy)."""
    def slope(h):
        return np.where(h > 0, 1.0, 0.01)

    mats = [(w[wo:wo + n_out * st].reshape(n_out, st)[:, :n_in].astype(np.float64), w[bo:bo + n_out].astype(np.float64))
            for wo, n_out, n_in, st, bo in layers]
    x64 = x.astype(np.float64)
    if y is not None:
        pre = (y.astype(np.float64)[:, None, :] + x64[None]).reshape(-1, x.shape[1])
        h = np.where(pre > 0, pre, 0.01 * pre)
    else:
        h = x64
    acts = [h]
    for li, (W, b) in enumerate(mats):
        z = h @ W.T + b
        h = np.where(z > 0, z, 0.01 * z) if li < len(mats) - 1 else z
        acts.append(h)
    gw = np.zeros(w.shape[0])
    g = dz.astype(np.float64)
    for li in range(len(mats) - 1, -1, -1):
        wo, n_out, n_in, st, bo = layers[li]
        gw[wo:wo + n_out * st].reshape(n_out, st)[:, :n_in] = g.T @ acts[li]
        gw[bo:bo + n_out] = g.sum(0)
        g = g @ mats[li][0]
        if li > 0 or y is not None:
            g = g * slope(acts[li])
    if y is None:
        return acts[-1], gw, g, None
    g = g.reshape(y.shape[0], x.shape[0], -1)
    return acts[-1], gw, g.sum(0), g.sum(1)


@pytest.mark.parametrize("loops", ["compiled", "numpy twins"])
@pytest.mark.parametrize("views", [0, 3])
def test_host_pass_matches_numpy_reference(views, loops, monkeypatch):
    """``HostPass`` (blocks, lanes, kept arrays) against the whole MLP in float64 NumPy: outputs
    and the gradients of weights, per-item and per-view inputs; with the fused loops and with
    their NumPy twins (what runs without Numba)."""
    from rfmitsuba.models.nn import host_loops, host_pass

    if loops == "numpy twins":
        monkeypatch.setattr(host_loops, "_loops", lambda: None)
    monkeypatch.setattr(host_pass, "HOST_BLOCK_ROWS", 8)
    monkeypatch.setattr(host_pass, "HOST_THREAD_MIN_ROWS", 0)
    x, y, w, layers, dz = _host_pass_case(np.random.default_rng(11), n=45, views=views, widths=(6, 16, 16, 4))
    p = host_pass.HostPass(x, y, w, layers, threads=2)
    assert len(p.lanes) == host_pass.HOST_LANES and p.threads == 2
    out = p.forward(np.empty(dz.shape, np.float32))
    gw, gx, gy = p.backward(dz)
    ref = _host_pass_reference(x, y, w, layers, dz)
    for got, want in zip((out, gw, gx, gy), ref):
        if want is None:
            assert got is None
            continue
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-4 * float(np.abs(want).max()))


@pytest.mark.parametrize("views", [0, 4])
def test_host_pass_bits_do_not_depend_on_threads(views):
    """One host thread or two: the same bits (fixed lanes, summed in lane order), at the size
    where the lanes start (``HOST_THREAD_MIN_ROWS``) and in blocks of ``HOST_BLOCK_ROWS``."""
    from rfmitsuba.models.nn import host_pass

    n = host_pass.HOST_THREAD_MIN_ROWS // max(views, 1) + 5
    x, y, w, layers, dz = _host_pass_case(np.random.default_rng(12), n=n, views=views, widths=(9, 32, 32, 3))
    results = []
    for threads in (1, 2):
        p = host_pass.HostPass(x, y, w, layers, threads=threads)
        assert p.threads == threads and len(p.lanes) == host_pass.HOST_LANES
        results.append((p.forward(np.empty(dz.shape, np.float32)),) + p.backward(dz))
    for a, b in zip(*results):
        if a is None:
            assert b is None
        else:
            assert np.array_equal(a, b)


def test_host_pass_releases_its_arrays_once():
    """The activations go back to the kept arrays after the backward pass; a second backward
    pass is an error naming why, not gradients from reused memory."""
    from rfmitsuba.models.nn import host_pass

    x, y, w, layers, dz = _host_pass_case(np.random.default_rng(13), n=20, views=2, widths=(5, 8, 2))
    p = host_pass.HostPass(x, y, w, layers)
    p.forward(np.empty(dz.shape, np.float32))
    kept = [a for a in p.acts if a is not x]
    p.backward(dz)
    assert p.acts is None
    taken = host_pass.BUFFERS.take(kept[0].shape)
    assert any(taken is a for a in kept)      # reused, not fresh memory
    host_pass.BUFFERS.give([taken])
    with pytest.raises(RuntimeError, match="backward pass ran already"):
        p.backward(dz)


def test_host_threads_restore_drjits_pool(variant):
    """A host MLP call on two lanes cuts Dr.Jit's pool to one thread while the host threads work
    and restores its count afterwards, forward and backward."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.models import nn
    from rfmitsuba.models.nn import host_pass

    if B.is_cuda():
        pytest.skip("the host products run on the LLVM backend only")
    before = dr.thread_count()
    seen = []
    real = host_pass.HostPass._run

    def spy(self, fn):
        seen.append((self.threads, dr.thread_count()))
        return real(self, fn)

    try:
        dr.set_thread_count(2)
        host_pass.HostPass._run = spy
        m = nn.MLP(4, 2, width=8, layers=1, seed=3, host=True)
        rng = np.random.default_rng(14)
        xs = [B.Float(rng.normal(size=host_pass.HOST_THREAD_MIN_ROWS).astype(np.float32)) for _ in range(4)]
        w = B.Float(m.weights)
        dr.enable_grad(w)
        m.set_weights(w)
        out = m(xs)
        dr.backward(dr.sum(out[0]) + dr.sum(out[1]))
        assert dr.thread_count() == 2
        assert seen == [(2, 1), (2, 1)]      # forward and backward, each with Dr.Jit on one thread
    finally:
        host_pass.HostPass._run = real
        dr.set_thread_count(before)
