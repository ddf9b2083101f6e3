"""Dr.Jit Bartlett PAS (rfmitsuba.rf.bartlett) against the NumPy reference, and its adjoint against
finite differences."""
from __future__ import annotations

import numpy as np
import pytest

from rfmitsuba.core.errors import ConfigError
from rfmitsuba.rf import bartlett_ref as P

F = 2.4e9


def _channels(n=3, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.normal(size=(n, 16)) + 1j * rng.normal(size=(n, 16))).astype(np.complex64)


@pytest.mark.parametrize("d", [1, 2])
def test_matches_numpy_reference(variant, d):
    from rfmitsuba.rf import bartlett

    h = _channels()
    ref = P.bartlett(h, frequency_hz=F, resolution_deg=d)
    raw = bartlett.bartlett(h.real, h.imag, frequency_hz=F, height=90 // d, width=360 // d, normalize=False).numpy()
    assert np.abs(raw - ref).max() <= 2e-6 * ref.max()
    nrm = bartlett.bartlett(h.real, h.imag, frequency_hz=F, height=90 // d, width=360 // d).numpy()
    assert np.abs(nrm - P.normalize(ref)).max() < 2e-6


@pytest.mark.parametrize("normalize, views, d", [(False, 2, 1), (True, 2, 1), (True, 1, 10), (True, 3, 2), (True, 18, 10)])
def test_gradient_matches_finite_differences(variant, normalize, views, d):
    """d/dh of sum(c * PAS) by the custom adjoint vs central differences of the float64 reference:
    one and several views (the forward pass unrolls them), and grids with fewer pixels than the
    backward pass's chunks (d = 10: 324 pixels) or a partial last chunk (d = 1, 2)."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.rf import bartlett

    h = _channels(views, seed=1).astype(np.complex128)
    H, W = 90 // d, 360 // d
    c = np.random.default_rng(2).normal(size=(views, H, W))
    hr, hi = B.Float(h.real.ravel().astype(np.float32)), B.Float(h.imag.ravel().astype(np.float32))
    dr.enable_grad(hr, hi)
    img = bartlett.bartlett(hr, hi, frequency_hz=F, height=H, width=W, normalize=normalize)
    dr.backward(dr.sum(img.array * B.Float(c.ravel().astype(np.float32))))
    g = np.asarray(dr.grad(hr), np.float64) + 1j * np.asarray(dr.grad(hi), np.float64)
    tol = 2e-3 * float(np.abs(g).max())

    def f(hh):
        w = P.beamformer(frequency_hz=F, resolution_deg=d).astype(np.complex128)
        img = np.abs(hh @ w.T).reshape(-1, H, W)
        if normalize:
            lo, hi_ = img.min(axis=(1, 2), keepdims=True), img.max(axis=(1, 2), keepdims=True)
            img = (img - lo) / (hi_ - lo)
        return float((img * c).sum())

    eps = 1e-5
    for k in sorted({0, 7, 16 * views - 11, 16 * views - 1}):
        e = np.zeros(h.shape, complex)
        e.flat[k] = eps
        fd_re = (f(h + e) - f(h - e)) / (2 * eps)
        fd_im = (f(h + 1j * e) - f(h - 1j * e)) / (2 * eps)
        assert g.flat[k].real == pytest.approx(fd_re, rel=2e-3, abs=tol)
        assert g.flat[k].imag == pytest.approx(fd_im, rel=2e-3, abs=tol)


def test_bad_input(variant):
    from rfmitsuba.rf import bartlett

    with pytest.raises(ConfigError, match="B\\*16"):
        bartlett.bartlett(np.zeros(15, np.float32), np.zeros(15, np.float32), frequency_hz=F)
    with pytest.raises(ConfigError, match="grid"):
        bartlett.bartlett(np.zeros(16, np.float32), np.zeros(16, np.float32), frequency_hz=F, height=7, width=360)
