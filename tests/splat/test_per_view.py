"""Tests of rfmitsuba.splat.per_view: view-major copies of per-Gaussian arrays whose gradient sums
the views with gathers (no atomics)."""
from __future__ import annotations

import numpy as np
import pytest


def _arrays(rng, n):
    from rfmitsuba.core import backend as B

    host = {"f": rng.normal(size=n), "v3": rng.normal(size=(n, 3)), "v4": rng.normal(size=(n, 4))}
    jit = [B.Float(host["f"].astype(np.float32)),
           B.Array3f(*[B.Float(host["v3"][:, k].astype(np.float32)) for k in range(3)]),
           B.Array4f(*[B.Float(host["v4"][:, k].astype(np.float32)) for k in range(4)])]
    return host, jit


@pytest.mark.parametrize("views", [1, 2, 5])
def test_per_view_copies_and_sums_the_views(variant, views):
    """Values: entry ``b * n + i`` is entry i. Gradients: entry i gets the sum of its ``views``
    entries' gradients (against NumPy in float64), for Float, Array3f and Array4f in one op."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.splat.per_view import per_view

    rng = np.random.default_rng(views)
    n = 37
    host, jit = _arrays(rng, n)
    for a in jit:
        dr.enable_grad(a)
    out = per_view(jit, views=views, n=n)
    assert len(out) == 3 and [dr.width(o) for o in out] == [views * n] * 3
    np.testing.assert_array_equal(out[0].numpy(), np.tile(host["f"].astype(np.float32), views))
    np.testing.assert_array_equal(np.asarray(out[2].numpy()).T, np.tile(host["v4"].astype(np.float32), (views, 1)))
    weights = [rng.normal(size=(views * n, k)) for k in (1, 3, 4)]
    loss = B.Float(0.0)
    for o, w in zip(out, weights):
        comps = [o] if w.shape[1] == 1 else [o[k] for k in range(w.shape[1])]
        for k, c in enumerate(comps):
            loss += dr.sum(c * B.Float(w[:, k].astype(np.float32)))
    dr.backward(loss)
    for a, w in zip(jit, weights):
        want = w.reshape(views, n, -1).sum(axis=0)
        got = np.asarray(dr.grad(a).numpy(), np.float64).reshape(-1, n).T if w.shape[1] > 1 \
            else np.asarray(dr.grad(a).numpy(), np.float64)[:, None]
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)


def test_per_view_forward_mode(variant):
    """Forward-mode AD repeats the input's tangent view-major."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.splat.per_view import per_view

    x = B.Float(1.0, 2.0, 3.0)
    dr.enable_grad(x)
    y, = per_view([x], views=2, n=3)
    dr.set_grad(x, B.Float(0.5, -1.0, 2.0))
    dr.forward_to(y)
    np.testing.assert_array_equal(dr.grad(y).numpy(), [0.5, -1.0, 2.0, 0.5, -1.0, 2.0])


def test_per_view_gradient_is_the_same_on_every_run(variant):
    """The views are summed in view order by one lane per entry, so repeated runs give the same
    bits (atomic additions from two threads need not)."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.splat.per_view import per_view

    rng = np.random.default_rng(3)
    n, views = 1000, 4
    g = rng.normal(size=views * n).astype(np.float32)
    runs = []
    for _ in range(3):
        x = B.Float(rng.normal(size=n).astype(np.float32))
        dr.enable_grad(x)
        y, = per_view([x], views=views, n=n)
        dr.backward(dr.sum(y * B.Float(g)))
        runs.append(np.asarray(dr.grad(x).numpy()))
    for r in runs[1:]:
        assert np.array_equal(r, runs[0])
    np.testing.assert_allclose(runs[0], g.reshape(views, n).sum(axis=0), rtol=1e-5, atol=1e-5)
