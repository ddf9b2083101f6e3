"""Tests of rfmitsuba.models.nn.host_ops: the host custom AD ops, against cooperative vectors."""
from __future__ import annotations

import numpy as np
import pytest


@pytest.mark.parametrize("block_rows,thread_min_rows", [(2048, 8192), (8, 8192), (8, 0)])
@pytest.mark.parametrize("pairs", [False, True])
def test_host_products_match_cooperative_vectors(variant, pairs, block_rows, thread_min_rows, monkeypatch):
    """The LLVM backend's host matrix products (``HostMLP``) give the cooperative-vector
    network's outputs and every gradient: weights, per-item and per-view inputs; in one
    block of rows, in blocks of 8 (37 rows: four full blocks and a partial one per view), and
    in blocks of 8 on two lanes (rows 0-17 and 18-36, on two host threads where Dr.Jit has two)."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.models.nn import MLP, host_pass

    monkeypatch.setattr(host_pass, "HOST_BLOCK_ROWS", block_rows)
    monkeypatch.setattr(host_pass, "HOST_THREAD_MIN_ROWS", thread_min_rows)

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


@pytest.mark.parametrize("extra", [0, 2])
def test_fused_host_network_matches_the_three_host_ops(variant, extra):
    """The EM network as one host op (:class:`HostEMNet`) gives the bits of its three host MLPs
    called one after the other: outputs, and the gradients of every weight buffer and of the
    Gaussian positions."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.models import nn
    from rfmitsuba.models.nn import host_ops, host_pass

    if B.is_cuda():
        pytest.skip("the host products run on the LLVM backend only")
    net = nn.EMNetwork(nn.NetConfig(width=16, gaussian_octaves=2, antenna_octaves=2), extra_inputs=extra, seed=4)
    rng = np.random.default_rng(15)
    pos_np = rng.random((host_pass.HOST_THREAD_MIN_ROWS // 3 + 7, 3)).astype(np.float32)
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
    real = host_ops.HostEMNet.op

    def spy():
        seen.append(True)
        return real()

    host_ops.HostEMNet.op = spy
    try:
        fused = run(True)
    finally:
        host_ops.HostEMNet.op = real
    assert seen, "the network did not run as one host op"
    for k, (a, b) in enumerate(zip(fused, run(False))):
        assert np.array_equal(a, b), k
