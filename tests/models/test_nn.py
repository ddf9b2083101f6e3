"""Tests of rfmitsuba.models.nn: encodings, packed MLPs and the EM-feature network."""
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


def test_sin_encoding_matches_numpy(variant):
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.nn import encode

    x = np.array([0.0, 0.1, 0.37, 0.5], np.float32)
    out = encode([B.Float(x)], octaves=3, kind="sin")
    assert len(out) == 1 + 2 * 3
    np.testing.assert_allclose(out[0].numpy(), x)
    for k in range(3):
        np.testing.assert_allclose(out[1 + 2 * k].numpy(), np.sin(2 * np.pi * 2 ** k * x), atol=2e-5)
        np.testing.assert_allclose(out[2 + 2 * k].numpy(), np.cos(2 * np.pi * 2 ** k * x), atol=2e-5)


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


def test_em_network_is_view_major_and_factorised(variant):
    """Output b*N+i equals the network evaluated for view b and Gaussian i alone."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.nn import EMNetwork, NetConfig

    net = EMNetwork(NetConfig(width=16, gaussian_octaves=2, antenna_octaves=2), seed=1)
    rng = np.random.default_rng(0)
    pos = rng.random((5, 3)).astype(np.float32)
    ant = rng.random((3, 3)).astype(np.float32)
    outs = net([B.Float(pos[:, k]) for k in range(3)], [B.Float(ant[:, k]) for k in range(3)])
    assert len(outs) == 3 and all(o.numpy().shape == (15,) for o in outs)
    for b in range(3):
        for i in range(5):
            one = net([B.Float(pos[i:i + 1, k]) for k in range(3)], [B.Float(ant[b:b + 1, k]) for k in range(3)])
            for o, o1 in zip(outs, one):
                assert abs(o.numpy()[b * 5 + i] - o1.numpy()[0]) < 1e-5


def test_em_network_extra_inputs_are_checked(variant):
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.nn import EMNetwork, NetConfig

    net = EMNetwork(NetConfig(width=8), extra_inputs=3, seed=0)
    p = [B.Float([0.5])] * 3
    with pytest.raises(ValueError, match="3 extra inputs"):
        net(p, p, None)
    s, a, d = net(p, p, [B.Float([0.2])] * 3)
    assert np.isfinite(s.numpy()).all()


def test_em_network_gradient_matches_finite_differences(variant):
    """Reverse-mode gradient of a loss (through a gather of the outputs, as the trainer does)
    w.r.t. the head weights equals central finite differences."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.models.nn import EMNetwork, NetConfig

    net = EMNetwork(NetConfig(width=8, gaussian_octaves=1, antenna_octaves=1, signal_bias=0.0), seed=2)
    if net.head.precision == "half":
        pytest.skip("finite differences of a float16 network measure its rounding (CUDA); "
                    "test_half_precision_matches_single checks the half-precision gradients on LLVM")
    rng = np.random.default_rng(3)
    pos = [B.Float(rng.random(4).astype(np.float32)) for _ in range(3)]
    ant = [B.Float(rng.random(2).astype(np.float32)) for _ in range(3)]
    w0 = np.array(net.head.weights.numpy(), np.float64)

    def loss_of(w):
        net.head.set_weights(w)
        s, a, _ = net(pos, ant)
        g = dr.gather(B.Float, s, B.UInt32([0, 3, 5, 5, 7]))  # backward is a scatter
        return dr.sum(dr.square(g)) + dr.sum(a * 0.5)

    w = B.Float(w0.astype(np.float32))
    dr.enable_grad(w)
    loss = loss_of(w)
    dr.backward(loss)
    grad = np.array(dr.grad(w).numpy(), np.float64)
    eps = 1e-2
    for j in [0, 5, len(w0) - 3, len(w0) - 1]:
        wp, wm = w0.copy(), w0.copy()
        wp[j] += eps
        wm[j] -= eps
        fd = (loss_of(wp.astype(np.float32)).numpy()[0] - loss_of(wm.astype(np.float32)).numpy()[0]) / (2 * eps)
        assert abs(fd - grad[j]) < 2e-3 + 2e-2 * abs(fd), (j, fd, grad[j])


@pytest.mark.parametrize("block_rows,thread_min_rows", [(2048, 8192), (8, 8192), (8, 0)])
@pytest.mark.parametrize("pairs", [False, True])
def test_host_products_match_cooperative_vectors(variant, pairs, block_rows, thread_min_rows, monkeypatch):
    """The LLVM backend's host matrix products (``_HostMLP``) give the cooperative-vector
    network's outputs and every gradient: weights, per-item and per-view inputs; in one
    block of rows, in blocks of 8 (37 rows: four full blocks and a partial one per view), and
    in blocks of 8 on two lanes (rows 0-17 and 18-36, on two host threads where Dr.Jit has two)."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.models import nn
    from rfmitsuba.models.nn import MLP

    monkeypatch.setattr(nn, "HOST_BLOCK_ROWS", block_rows)
    monkeypatch.setattr(nn, "HOST_THREAD_MIN_ROWS", thread_min_rows)

    if B.is_cuda():
        pytest.skip("the host products run on the LLVM backend only")
    rng = np.random.default_rng(4)
    x = rng.normal(size=(37, 6)).astype(np.float32)
    y = rng.normal(size=(3, 6)).astype(np.float32)
    results = []
    for host in (True, False):
        m = MLP(6, 3, width=16, layers=2, seed=7, host=host)
        assert (m._host_layers is not None) == host
        # random weights (not m.weights.numpy(): reading a packed buffer before replacing it
        # leaves Dr.Jit 1.5's cooperative-vector views without their gradient link)
        w = B.Float(np.random.default_rng(6).normal(0, 0.3, m.num_parameters).astype(np.float32))
        dr.enable_grad(w)
        m.set_weights(w)
        xs, ys = [B.Float(x[:, k]) for k in range(6)], [B.Float(y[:, k]) for k in range(6)]
        for v in xs + ys:
            dr.enable_grad(v)
        out = m.pairs(xs, ys) if pairs else m(xs)
        g = dr.gather(B.Float, out[0], B.UInt32([0, 3, 5, 5, 30]))   # a scatter in the backward
        dr.backward(dr.sum(dr.square(g)) + dr.sum(out[1] * 0.5) - dr.sum(out[2] * out[0]))
        results.append([np.stack([o.numpy() for o in out]), dr.grad(w).numpy(),
                        np.stack([dr.grad(v).numpy() for v in xs])]
                       + ([np.stack([dr.grad(v).numpy() for v in ys])] if pairs else []))
    assert results[0][0].shape == (3, 37 * 3 if pairs else 37)
    for a, b in zip(*results):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-4 * float(np.abs(b).max()))


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


def test_precision_names_are_checked(variant):
    from rfmitsuba.core import backend as B
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.nn import MLP, NetConfig, resolve_precision

    assert resolve_precision("auto") == ("half" if B.is_cuda() else "single")
    with pytest.raises(ConfigError, match="precision must be one of auto, single, half, got 'double'"):
        MLP(2, 1, width=4, layers=1, seed=0, precision="double")
    with pytest.raises(ConfigError, match="NetConfig.precision"):
        NetConfig(precision="fp16")


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


def test_hashgrid_network_runs_and_has_parameters(variant):
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.nn import EMNetwork, NetConfig

    cfg = NetConfig(encoding="hashgrid", width=8, hash_levels=2, hash_log2_size=8)
    net = EMNetwork(cfg, seed=0)
    assert "hash" in net.modules() and net.modules()["hash"].num_parameters > 0
    p = [B.Float([0.1, 0.9])] * 3
    s, a, d = net(p, [B.Float([0.5])] * 3)
    assert s.numpy().shape == (2,)


def test_bad_config_is_an_error():
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.nn import NetConfig

    with pytest.raises(ConfigError, match="width"):
        NetConfig(width=0)
    with pytest.raises(ConfigError, match="gaussian_octaves"):
        NetConfig(gaussian_octaves=-1)


def test_host_columns_read_kept_uploads_without_a_kernel(variant):
    """The hand-off between two host MLPs (trunk -> head forward, head -> trunk backward): columns
    of a recent kept upload give back the very host array, and no kernel runs; other columns are
    evaluated together and stacked; an empty list gives None."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.core.upload import empty_aligned
    from rfmitsuba.models import nn

    if B.is_cuda():
        pytest.skip("the host products run on the LLVM backend only")
    host = empty_aligned((37, 5))
    host[...] = np.random.default_rng(5).normal(size=(37, 5))
    kept = nn._upload_kept(B.Float, host)
    lazy = [B.Float(np.arange(37, dtype=np.float32)) * float(k + 1) for k in range(3)]
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        got_kept, got_none = nn._host_columns([kept, []])
        ran = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
        got_lazy, = nn._host_columns([lazy])
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert got_kept is host and got_none is None and ran == []
    np.testing.assert_array_equal(got_lazy, np.arange(37, dtype=np.float32)[:, None] * np.arange(1, 4))


@pytest.mark.parametrize("pairs", [False, True])
def test_host_products_compile_once(variant, pairs):
    """The host products' outputs and gradients are uploads in aligned memory, so the kernels that
    read them compile once however NumPy's allocations fall (a borrowed array's alignment is part
    of a kernel: the splat field's Stage-1 step compiled 17 kernels in 20 steps before, 25 ms each).
    Between steps, small allocations of changing size move NumPy's heap."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.models.nn import MLP

    if B.is_cuda():
        pytest.skip("the host products run on the LLVM backend only")
    rng = np.random.default_rng(11)
    m = MLP(6, 3, width=16, layers=2, seed=7, host=True)
    w = B.Float(rng.normal(0, 0.3, m.num_parameters).astype(np.float32))
    dr.enable_grad(w)
    m.set_weights(w)
    keep, misses = [], []
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        for step in range(8):
            dr.kernel_history()
            x = rng.normal(size=(37, 6)).astype(np.float32)
            y = rng.normal(size=(3, 6)).astype(np.float32)
            xs, ys = [B.Float(x[:, k]) for k in range(6)], [B.Float(y[:, k]) for k in range(6)]
            for v in xs + ys:
                dr.enable_grad(v)
            out = m.pairs(xs, ys) if pairs else m(xs)
            loss = dr.sum(out[0] * out[1] - 0.5 * out[2])
            dr.backward(loss)
            dr.eval(loss, dr.grad(w), [dr.grad(v) for v in xs + ys])
            misses.append(sum(1 for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT
                              and not k["cache_hit"]))
            keep.append(np.empty(1 + 3 * step, np.float32))      # the heap moves
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert misses[2:] == [0] * 6, misses


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
    """``_HostPass`` (blocks, lanes, kept arrays) against the whole MLP in float64 NumPy: outputs
    and the gradients of weights, per-item and per-view inputs; with the fused loops and with
    their NumPy twins (what runs without Numba)."""
    from rfmitsuba.models import host_loops, nn

    if loops == "numpy twins":
        monkeypatch.setattr(host_loops, "_loops", lambda: None)
    monkeypatch.setattr(nn, "HOST_BLOCK_ROWS", 8)
    monkeypatch.setattr(nn, "HOST_THREAD_MIN_ROWS", 0)
    x, y, w, layers, dz = _host_pass_case(np.random.default_rng(11), n=45, views=views, widths=(6, 16, 16, 4))
    p = nn._HostPass(x, y, w, layers, threads=2)
    assert len(p.lanes) == nn.HOST_LANES and p.threads == 2
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
    from rfmitsuba.models import nn

    n = nn.HOST_THREAD_MIN_ROWS // max(views, 1) + 5
    x, y, w, layers, dz = _host_pass_case(np.random.default_rng(12), n=n, views=views, widths=(9, 32, 32, 3))
    results = []
    for threads in (1, 2):
        p = nn._HostPass(x, y, w, layers, threads=threads)
        assert p.threads == threads and len(p.lanes) == nn.HOST_LANES
        results.append((p.forward(np.empty(dz.shape, np.float32)),) + p.backward(dz))
    for a, b in zip(*results):
        if a is None:
            assert b is None
        else:
            assert np.array_equal(a, b)


def test_host_pass_releases_its_arrays_once():
    """The activations go back to the kept arrays after the backward pass; a second backward
    pass is an error naming why, not gradients from reused memory."""
    from rfmitsuba.models import nn

    x, y, w, layers, dz = _host_pass_case(np.random.default_rng(13), n=20, views=2, widths=(5, 8, 2))
    p = nn._HostPass(x, y, w, layers)
    p.forward(np.empty(dz.shape, np.float32))
    kept = [a for a in p.acts if a is not x]
    p.backward(dz)
    assert p.acts is None
    taken = nn._BUFFERS.take(kept[0].shape)
    assert any(taken is a for a in kept)      # reused, not fresh memory
    nn._BUFFERS.give([taken])
    with pytest.raises(RuntimeError, match="backward pass ran already"):
        p.backward(dz)


def test_host_threads_restore_drjits_pool(variant):
    """A host MLP call on two lanes cuts Dr.Jit's pool to one thread while the host threads work
    and restores its count afterwards, forward and backward."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.models import nn

    if B.is_cuda():
        pytest.skip("the host products run on the LLVM backend only")
    before = dr.thread_count()
    seen = []
    real = nn._HostPass._run

    def spy(self, fn):
        seen.append((self.threads, dr.thread_count()))
        return real(self, fn)

    try:
        dr.set_thread_count(2)
        nn._HostPass._run = spy
        m = nn.MLP(4, 2, width=8, layers=1, seed=3, host=True)
        rng = np.random.default_rng(14)
        xs = [B.Float(rng.normal(size=nn.HOST_THREAD_MIN_ROWS).astype(np.float32)) for _ in range(4)]
        w = B.Float(m.weights)
        dr.enable_grad(w)
        m.set_weights(w)
        out = m(xs)
        dr.backward(dr.sum(out[0]) + dr.sum(out[1]))
        assert dr.thread_count() == 2
        assert seen == [(2, 1), (2, 1)]      # forward and backward, each with Dr.Jit on one thread
    finally:
        nn._HostPass._run = real
        dr.set_thread_count(before)


@pytest.mark.parametrize("extra", [0, 2])
def test_fused_host_network_matches_the_three_host_ops(variant, extra):
    """The EM network as one host op (:class:`_HostEMNet`) gives the bits of its three host MLPs
    called one after the other: outputs, and the gradients of every weight buffer and of the
    Gaussian positions."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.models import nn

    if B.is_cuda():
        pytest.skip("the host products run on the LLVM backend only")
    net = nn.EMNetwork(nn.NetConfig(width=16, gaussian_octaves=2, antenna_octaves=2), extra_inputs=extra, seed=4)
    rng = np.random.default_rng(15)
    pos_np = rng.random((nn.HOST_THREAD_MIN_ROWS // 3 + 7, 3)).astype(np.float32)
    ant_np = rng.random((3, 3)).astype(np.float32)
    ex = [B.Float(rng.random(3).astype(np.float32)) for _ in range(extra)] or None

    def run(fused):
        pos = [B.Float(pos_np[:, k]) for k in range(3)]
        ws = [B.Float(dr.detach(m.weights)) for m in (net.gaussian, net.antenna, net.head)]
        for w, m in zip(ws, (net.gaussian, net.antenna, net.head)):
            dr.enable_grad(w)
            m.set_weights(w)
        dr.enable_grad(pos)
        ant = [B.Float(ant_np[:, k]) for k in range(3)]
        if fused:
            out = net(pos, ant, ex)
        else:
            out = net.head.pairs(net.gaussian_features(pos), net.antenna_features(ant, ex))
        dr.backward(dr.sum(dr.square(out[0])) + dr.sum(out[1] * 0.5) + dr.sum(dr.gather(B.Float, out[2], B.UInt32([1, 4, 4]))))
        return [o.numpy().copy() for o in out] + [dr.grad(w).numpy().copy() for w in ws] \
            + [dr.grad(p).numpy().copy() for p in pos]

    seen = []
    real = nn._HostEMNet.op

    def spy():
        seen.append(True)
        return real()

    nn._HostEMNet.op = spy
    try:
        fused = run(True)
    finally:
        nn._HostEMNet.op = real
    assert seen, "the network did not run as one host op"
    for k, (a, b) in enumerate(zip(fused, run(False))):
        assert np.array_equal(a, b), k
