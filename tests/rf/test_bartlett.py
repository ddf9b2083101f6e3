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


def _image_and_grad(h, c, *, normalize, d, host):
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.rf import bartlett

    H, W = 90 // d, 360 // d
    hr, hi = B.Float(h.real.ravel().astype(np.float32)), B.Float(h.imag.ravel().astype(np.float32))
    dr.enable_grad(hr, hi)
    img = bartlett.bartlett(hr, hi, frequency_hz=F, height=H, width=W, normalize=normalize, host=host)
    dr.backward(dr.sum(img.array * B.Float(c.ravel().astype(np.float32))))
    return img.numpy(), np.asarray(dr.grad(hr), np.float64) + 1j * np.asarray(dr.grad(hi), np.float64)


@pytest.mark.parametrize("normalize, views, d", [(False, 2, 1), (True, 3, 1), (True, 1, 10), (True, 18, 2)])
def test_host_products_and_kernels_agree(variant, normalize, views, d):
    """The host op (rfmitsuba.rf.bartlett_host) and the Dr.Jit kernels: the same images and
    gradients to float32 rounding, with one lane (d = 10, one view) and two."""
    from rfmitsuba.core import backend as B

    if B.is_cuda():
        pytest.skip("the host products run on the LLVM backend only")
    h = _channels(views, seed=4)
    c = np.random.default_rng(5).normal(size=(views, 90 // d, 360 // d))
    img_h, g_h = _image_and_grad(h, c, normalize=normalize, d=d, host=True)
    img_k, g_k = _image_and_grad(h, c, normalize=normalize, d=d, host=False)
    assert np.abs(img_h - img_k).max() <= 2e-6 * max(1.0, np.abs(img_k).max())
    assert np.abs(g_h - g_k).max() <= 1e-4 * np.abs(g_k).max()


def test_host_adjoint_sends_the_extremes_gradient_to_every_pixel_that_ties(variant):
    """One element alone draws an image flat but for the last float bits, with many pixels tied
    at its minimum and at its maximum: the gradient through each extreme goes to all of them,
    as in the kernels (float64 reference on the host forward pass's own values)."""
    from rfmitsuba.rf import bartlett_host
    from rfmitsuba.rf.bartlett_ref import beamformer

    h = np.zeros((2, 16), np.complex64)
    h[0, 5], h[1] = 0.7 - 0.2j, _channels(1, seed=6)[0]
    g = np.random.default_rng(7).normal(size=(2, 9 * 36)).astype(np.float32)
    im = bartlett_host.Images(h, frequency_hz=F, height=9, width=36, normalize=True, threads=1, keep=True)
    p, pn = im.p.astype(np.float64), im.out.astype(np.float64)
    y = im.yr.astype(np.float64) + 1j * im.yi.astype(np.float64)
    lo, hi = p.min(1, keepdims=True), p.max(1, keepdims=True)
    assert (p[0] == lo[0]).sum() > 1 and (p[0] == hi[0]).sum() > 1
    inv = 1.0 / np.maximum(hi - lo, 1e-30)
    gp = g * inv + (p == lo) * ((g * (pn - 1)).sum(1, keepdims=True) * inv) \
        + ((p == hi) & (p != lo)) * (-(g * pn).sum(1, keepdims=True) * inv)
    want = (gp / np.maximum(p, 1e-30) * y) @ np.conj(beamformer(frequency_hz=F, resolution_deg=10)).astype(complex)
    got = im.backward(g)
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5 * np.abs(want).max())


def test_host_lanes_give_the_same_bits_on_one_thread_or_two(variant):
    from rfmitsuba.rf import bartlett_host

    h = _channels(4, seed=8)
    g = np.random.default_rng(9).normal(size=(4, 90 * 360)).astype(np.float32)
    assert len(bartlett_host.lane_cuts(90 * 360, 4)) == bartlett_host.LANES + 1
    runs = []
    for threads in (1, 2):
        im = bartlett_host.Images(h, frequency_hz=F, height=90, width=360, normalize=True, threads=threads,
                                  keep=True)
        out = im.out.copy()
        runs.append((out, im.backward(g)))
    assert np.array_equal(runs[0][0], runs[1][0]) and np.array_equal(runs[0][1], runs[1][1])
    with pytest.raises(RuntimeError, match="backward ran already"):
        im.backward(g)


def test_a_recorded_function_runs_the_kernels(variant):
    """Inside ``drjit.freeze`` the default read-out runs the kernels (host code read back there
    would be kept in the recording): the recording and its replay give the kernels' bits for
    each call's channels; host=True there is refused."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.core.upload import upload
    from rfmitsuba.rf import bartlett

    H, W = 9, 36
    w = list(bartlett.weights(frequency_hz=F, height=H, width=W))

    @dr.freeze
    def frozen(hr, hi, w):
        return bartlett.bartlett(hr, hi, frequency_hz=F, height=H, width=W).array

    for seed in (10, 11, 12):
        h = _channels(2, seed=seed)
        # aligned uploads: the alignment of borrowed memory is part of what a recording is for
        hr, hi = upload(B.Float, h.real.ravel()), upload(B.Float, h.imag.ravel())
        want = bartlett.bartlett(hr, hi, frequency_hz=F, height=H, width=W, host=False).numpy().ravel()
        assert np.array_equal(frozen(hr, hi, w).numpy(), want)
    assert frozen.n_recordings == 1

    @dr.freeze
    def forced(hr, hi, w):
        return bartlett.bartlett(hr, hi, frequency_hz=F, height=H, width=W, host=True).array

    with pytest.raises(Exception) as err:
        forced(hr, hi, w)
    chain, e = [], err.value
    while e is not None:
        chain.append(str(e))
        e = e.__cause__ or e.__context__
    assert any("drjit.freeze" in m for m in chain), chain


def test_host_close_calls_at_the_extremes_are_settled_in_float64(variant):
    """Two pixels 7.6e-8 apart at an image's maximum (the benchmark's channels, 3 views, seed 0),
    closer than the float32 products can tell: settled in float64, the maximum is the exact one
    and the pixels near it hold their correctly rounded amplitudes."""
    from rfmitsuba.rf import bartlett_host
    from rfmitsuba.rf.bartlett_ref import beamformer

    rng = np.random.default_rng(0)
    h = (rng.normal(size=(3, 16)) + 1j * rng.normal(size=(3, 16))).astype(np.complex64)
    exact = np.abs(h.astype(np.complex128) @ beamformer(frequency_hz=F).astype(np.complex128).T)
    top = np.argsort(exact[0])[-2:]
    assert exact[0, top[1]] - exact[0, top[0]] < 1e-7 * exact[0].max()
    im = bartlett_host.Images(h, frequency_hz=F, height=90, width=360, normalize=True, threads=1, keep=True)
    assert im.near[0, 1] >= 2
    assert np.array_equal(im.p.argmax(1), exact.argmax(1)) and np.array_equal(im.p.argmin(1), exact.argmin(1))
    assert np.array_equal(im.p[0, top], exact[0, top].astype(np.float32))
    assert im.out[0, top[1]] == 1.0 and im.out[0, top[0]] < 1.0
