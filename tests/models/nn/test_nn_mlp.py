"""Tests of rfmitsuba.models.nn.mlp: packed MLPs, against a NumPy forward pass."""
from __future__ import annotations

import numpy as np
import pytest


def _mlp_numpy(layers, x):
    """Reference forward pass over ``MLP.layer_arrays()``: ``h @ W.T + b`` per layer,
    LeakyReLU(0.01) between layers."""
    h = x
    for li, (W, b) in enumerate(layers):
        h = h @ W.T + b
        if li < len(layers) - 1:
            h = np.where(h > 0, h, 0.01 * h)
    return h


def _tolerance(m) -> dict:
    """Float16 products (CUDA's cooperative vectors) against a float32 reference."""
    return {"rtol": 1e-5, "atol": 1e-5} if m.precision == "single" else {"rtol": 2e-2, "atol": 2e-2}


@pytest.mark.parametrize("precision", ["auto", "half"])
def test_mlp_forward_matches_numpy(variant, precision):
    """The packed network against NumPy on the weights read back from its buffer (any layout)."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.nn import MLP

    m = MLP(3, 2, width=8, layers=2, seed=3, precision=precision)
    w = np.random.default_rng(1).normal(0, 0.5, m.buffer_size).astype(np.float32)
    m.set_weights(w)
    x = np.random.default_rng(0).random((7, 3)).astype(np.float32)
    out = np.stack([o.numpy() for o in m([B.Float(x[:, k]) for k in range(3)])], 1)
    layers = m.layer_arrays()
    assert [W.shape for W, _ in layers] == [(8, 3), (8, 8), (2, 8)]
    assert m.num_parameters == 3 * 8 + 8 + 8 * 8 + 8 + 8 * 2 + 2 <= m.buffer_size
    if m.precision == "single" and not B.is_cuda():   # LLVM packs row-major: W then b per layer
        np.testing.assert_array_equal(np.concatenate([a.ravel() for wb in layers for a in wb]), w)
    np.testing.assert_allclose(out, _mlp_numpy(layers, x), **_tolerance(m))


def test_mlp_seed_determines_weights(variant):
    from rfmitsuba.models.nn import MLP

    a = MLP(4, 3, width=16, layers=1, seed=5).weights.numpy()
    b = MLP(4, 3, width=16, layers=1, seed=5).weights.numpy()
    c = MLP(4, 3, width=16, layers=1, seed=6).weights.numpy()
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_mlp_wrong_weight_shape_is_an_error(variant):
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.nn import MLP

    m = MLP(3, 2, width=4, layers=1, seed=0)
    with pytest.raises(ConfigError, match="expected shape"):
        m.set_weights(np.zeros(m.buffer_size + 1, np.float32))


@pytest.mark.parametrize("pairs", [False, True])
def test_half_precision_matches_single(variant, pairs):
    """``precision="half"`` (CUDA's only cooperative-vector format for training in Dr.Jit 1.5)
    gives the single-precision network's outputs and every gradient to float16 accuracy, and its
    trainable weights stay float32 (the master copy the optimizer updates)."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.models.nn import MLP

    if B.is_cuda():
        pytest.skip("single precision is not available on CUDA")
    rng = np.random.default_rng(8)
    x = rng.uniform(-1, 1, size=(41, 6)).astype(np.float32)
    y = rng.uniform(-1, 1, size=(3, 6)).astype(np.float32)
    w = np.random.default_rng(9).normal(0, 0.3, MLP(6, 3, width=16, layers=2, seed=7).num_parameters)
    results = []
    for precision in ("single", "half"):
        m = MLP(6, 3, width=16, layers=2, seed=7, precision=precision)
        assert m.precision == precision and m.num_parameters == len(w)
        wd = B.Float(w.astype(np.float32))
        dr.enable_grad(wd)
        m.set_weights(wd)
        assert type(m.weights) is B.Float
        xs, ys = [B.Float(x[:, k]) for k in range(6)], [B.Float(y[:, k]) for k in range(6)]
        for v in xs + ys:
            dr.enable_grad(v)
        out = m.pairs(xs, ys) if pairs else m(xs)
        dr.backward(dr.sum(dr.square(out[0])) + dr.sum(out[1] * 0.5) - dr.sum(out[2] * out[0]))
        results.append([np.stack([o.numpy() for o in out]), dr.grad(wd).numpy(),
                        np.stack([dr.grad(v).numpy() for v in xs])])
    for a, b in zip(*results):
        np.testing.assert_allclose(b, a, rtol=0, atol=2e-2 * float(np.abs(a).max()))
    assert np.abs(results[0][1] - results[1][1]).max() > 0   # the half path really ran in float16


def test_mlp_pairs_are_view_major(variant):
    """``MLP.pairs`` row ``b * N + i`` is the network on ``act(x_i + y_b)``."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.nn import MLP

    m = MLP(4, 2, width=8, layers=1, seed=1)
    rng = np.random.default_rng(5)
    x, y = rng.normal(size=(5, 4)).astype(np.float32), rng.normal(size=(2, 4)).astype(np.float32)
    out = np.stack([o.numpy() for o in m.pairs([B.Float(x[:, k]) for k in range(4)],
                                               [B.Float(y[:, k]) for k in range(4)])], 1)
    h = (y[:, None, :] + x[None]).reshape(-1, 4)
    h = np.where(h > 0, h, 0.01 * h)
    np.testing.assert_allclose(out, _mlp_numpy(m.layer_arrays(), h), **_tolerance(m))
    with pytest.raises(ValueError, match="4 inputs per item and per view"):
        m.pairs([B.Float(x[:, 0])], [B.Float(y[:, 0])])
