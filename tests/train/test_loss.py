"""Tests of rfmitsuba.train.loss: parity with skimage, finite-difference gradients, the loss."""
from __future__ import annotations

import drjit as dr
import numpy as np
import pytest
from skimage.metrics import structural_similarity

from rfmitsuba.core import backend as B
from rfmitsuba.core.ssim import ssim_images
from rfmitsuba.train import loss as S


def smooth_images(rng, b, h, w):
    """PAS-like images: a few Gaussian blobs plus a little noise, in [0, 1]."""
    yy, xx = np.mgrid[0:h, 0:w]
    out = np.zeros((b, h, w))
    for k in range(b):
        for _ in range(4):
            cy, cx, s = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(3, 15)
            out[k] += rng.uniform(0.2, 1) * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * s * s))
    out += 0.01 * rng.normal(size=out.shape)
    return np.clip(out / out.max(), 0, 1)


def test_matches_skimage_on_random_and_smooth_images(variant):
    rng = np.random.default_rng(0)
    cases = [
        (rng.random((3, 90, 360)), rng.random((3, 90, 360))),
        (smooth_images(rng, 3, 90, 360), smooth_images(rng, 3, 90, 360)),
        (smooth_images(rng, 2, 18, 72), None),  # vs a noisy copy of itself
        (rng.random((1, 7, 9)), rng.random((1, 7, 9))),  # one window row
    ]
    for pred, gt in cases:
        if gt is None:
            gt = np.clip(pred + 0.05 * rng.normal(size=pred.shape), 0, 1)
        pred, gt = pred.astype(np.float32), gt.astype(np.float32)
        ours = S.ssim(B.TensorXf(pred), B.TensorXf(gt)).numpy()
        theirs = [structural_similarity(p.astype(np.float64), g.astype(np.float64), data_range=1.0)
                  for p, g in zip(pred, gt)]
        assert np.abs(ours - theirs).max() < 1e-4, (ours, theirs)
        assert np.allclose(ssim_images(pred, gt), theirs)


def test_identical_images_and_2d_input(variant):
    rng = np.random.default_rng(1)
    x = rng.random((20, 30)).astype(np.float32)
    assert S.ssim(B.TensorXf(x), B.TensorXf(x)).numpy() == pytest.approx([1.0], abs=1e-6)
    assert ssim_images(x[None], x[None]) == pytest.approx([1.0])


def test_gradient_matches_finite_differences_of_skimage(variant):
    # Reference: central differences of skimage's float64 SSIM on a 9x11 image.
    rng = np.random.default_rng(2)
    pred = rng.random((9, 11))
    gt = rng.random((9, 11))
    x = B.TensorXf(np.float32(pred))
    dr.enable_grad(x)
    value = S.ssim(x, B.TensorXf(np.float32(gt)))
    dr.backward(value)
    grad = dr.grad(x).numpy()
    fd = np.zeros_like(pred)
    eps = 1e-6
    for idx in np.ndindex(pred.shape):
        p1, p2 = pred.copy(), pred.copy()
        p1[idx] += eps
        p2[idx] -= eps
        fd[idx] = (structural_similarity(p1, gt, data_range=1.0)
                   - structural_similarity(p2, gt, data_range=1.0)) / (2 * eps)
    assert np.abs(grad - fd).max() < 1e-3 * np.abs(fd).max()


def test_gradient_with_respect_to_both_images(variant):
    """With gradients on both images (all five window sums go backward), each image's gradient is
    the one of the fixed-target path (three sums backward) with the arguments swapped, as SSIM is
    symmetric."""
    rng = np.random.default_rng(3)
    a, b = np.float32(rng.random((2, 12, 13))), np.float32(rng.random((2, 12, 13)))

    def grads(first, second, both):
        x, y = B.TensorXf(first), B.TensorXf(second)
        dr.enable_grad(x)
        if both:
            dr.enable_grad(y)
        dr.backward(dr.sum(S.ssim(x, y)))
        return dr.grad(x).numpy(), (dr.grad(y).numpy() if both else None)

    gx, gy = grads(a, b, True)
    assert np.abs(gx - grads(a, b, False)[0]).max() < 1e-6
    assert np.abs(gy - grads(b, a, False)[0]).max() < 1e-6
    assert np.abs(gy).max() > 1e-3


def test_loss_is_weighted_l1_and_ssim(variant):
    rng = np.random.default_rng(3)
    pred = rng.random((2, 12, 20)).astype(np.float32)
    gt = rng.random((2, 12, 20)).astype(np.float32)
    expected = 0.8 * np.abs(pred - gt).mean() + 0.2 * (1 - np.mean(ssim_images(pred, gt)))
    x = B.TensorXf(pred)
    dr.enable_grad(x)
    value = S.loss(x, B.TensorXf(gt))
    assert value.numpy()[0] == pytest.approx(expected, abs=1e-5)
    dr.backward(value)
    assert np.all(np.isfinite(dr.grad(x).numpy()))
    assert S.loss(B.TensorXf(gt), B.TensorXf(gt)).numpy()[0] == pytest.approx(0.0, abs=1e-6)


def test_bad_shapes(variant):
    a = B.TensorXf(np.zeros((2, 10, 10), np.float32))
    with pytest.raises(S.ImageError, match="differ in shape"):
        S.ssim(a, B.TensorXf(np.zeros((2, 10, 11), np.float32)))
    with pytest.raises(S.ImageError, match="at least 7x7"):
        S.ssim(B.TensorXf(np.zeros((1, 6, 10), np.float32)), B.TensorXf(np.zeros((1, 6, 10), np.float32)))
    with pytest.raises(S.ImageError, match="\\[B, H, W\\]"):
        S.loss(B.TensorXf(np.zeros(10, np.float32)), B.TensorXf(np.zeros(10, np.float32)))
    with pytest.raises(S.ImageError):
        ssim_images(np.zeros((1, 10, 10)), np.zeros((1, 10, 11)))


@pytest.mark.parametrize("outer,length,inner", [(3, 40, 1), (2, 23, 5), (1, 7, 4), (4, 9, 3)])
def test_window_sums_and_adjoint_match_seven_term_sums_bit_for_bit(variant, outer, length, inner):
    # The sliding passes of _BoxSum (the window kept in registers, SEGMENT positions per lane)
    # against a plain NumPy twin that adds the seven terms in the same order, in float32: the
    # same bits, forward and backward, for segments that end early (length - 6 not a multiple of
    # SEGMENT) and a single window (length 7).
    rng = np.random.default_rng(outer * 100 + length)
    xs = [np.float32(rng.normal(size=(outer, length, inner))) for _ in range(2)]
    lo = length - S.WIN + 1
    args = [B.Float(x.ravel()) for x in xs]
    for a in args:
        dr.enable_grad(a)
    out = dr.custom(S._BoxSum, args, outer, length, inner)
    weights = [np.float32(rng.normal(size=(outer, lo, inner))) for _ in xs]
    dr.backward(sum(dr.sum(o * B.Float(w.ravel())) for o, w in zip(out, weights)))
    for x, o, a, w in zip(xs, out, args, weights):
        want = np.zeros((outer, lo, inner), np.float32)
        for d in range(S.WIN):
            want += x[:, d:d + lo]
        assert np.array_equal(o.numpy().reshape(outer, lo, inner), want)
        grad = np.zeros((outer, length, inner), np.float32)
        for d in range(S.WIN):     # input i gets the weights at i, i - 1, ..., i - 6, in that order
            shifted = np.zeros_like(grad)
            shifted[:, d:d + lo] = w
            grad += shifted
        assert np.array_equal(dr.grad(a).numpy().reshape(outer, length, inner), grad)
