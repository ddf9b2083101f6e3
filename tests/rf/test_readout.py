"""Tests of rfmitsuba.rf.readout: the Bartlett kernel and the differentiable read-out."""
from __future__ import annotations

import numpy as np


def test_kernel_is_the_array_response():
    """K[p, q] equals |a(p)^H a(q)| / 16 computed from rfmitsuba.rf.array's element positions."""
    from rfmitsuba.rf import array as antenna
    from rfmitsuba.rf.readout import bartlett_kernel

    rng = np.random.default_rng(0)
    el_o, az_o = rng.uniform(0, np.pi / 2, 5), rng.uniform(0, 2 * np.pi, 5)
    el_i, az_i = rng.uniform(0, np.pi / 2, 4), rng.uniform(0, 2 * np.pi, 4)
    K = bartlett_kernel(el_o, az_o, el_i, az_i)
    lam = antenna.wavelength(2.4e9)
    e = antenna.element_positions(2.4e9)[:, :2] / lam

    def steer(el, az):
        return np.exp(-2j * np.pi * (e[:, 0] * np.cos(el) * np.cos(az) + e[:, 1] * np.cos(el) * np.sin(az)))

    for p in range(5):
        for q in range(4):
            ref = abs(np.conj(steer(el_o[p], az_o[p])) @ steer(el_i[q], az_i[q])) / 16
            assert abs(K[p, q] - ref) < 1e-5
    same = bartlett_kernel(el_i, az_i, el_i, az_i)
    np.testing.assert_allclose(np.diag(same), 1.0, atol=1e-6)


def test_readout_is_linear_with_transposed_gradient(variant):
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.rf.readout import BartlettReadout

    r = BartlettReadout(6, 24, 9, 36)
    x = np.random.default_rng(1).random((2, 6, 24)).astype(np.float32)
    xt = B.TensorXf(x)
    dr.enable_grad(xt)
    y = r(xt)
    assert y.shape == (2, 9, 36)
    ref = x.reshape(2, -1) @ r.kernel.T
    np.testing.assert_allclose(np.array(y.numpy()).reshape(2, -1), ref, rtol=1e-5, atol=1e-6)
    w = np.random.default_rng(2).random(2 * 9 * 36).astype(np.float32)
    dr.backward(dr.sum(y.array * B.Float(w)))
    g = np.array(dr.grad(xt).numpy()).reshape(2, -1)
    np.testing.assert_allclose(g, w.reshape(2, -1) @ r.kernel, rtol=1e-5, atol=1e-6)
