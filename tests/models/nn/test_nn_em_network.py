"""Tests of rfmitsuba.models.nn.em_network: the EM-feature network."""
from __future__ import annotations

import numpy as np
import pytest


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
