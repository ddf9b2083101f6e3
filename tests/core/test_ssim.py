"""Tests of rfmitsuba.core.ssim: the metric protocol's SSIM against a plain NumPy twin.

The protocol (SPEC, "Metric protocol") is skimage's SSIM with data range 1 and its default
7 x 7 uniform window, sample covariances (N / (N - 1)), K1 = 0.01, K2 = 0.03, averaged over the
pixels whose window lies inside the image. The twin below writes that definition out, so a change
of skimage's defaults (or of our call) fails here rather than moving every table a little.
"""
import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from rfmitsuba.core.errors import ImageError
from rfmitsuba.core.ssim import ssim_images


def ssim_twin(x: np.ndarray, y: np.ndarray, *, win: int = 7) -> float:
    """SSIM of two float images [H, W] in [0, 1] by the protocol's definition (float64)."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)

    def mean(a):
        return sliding_window_view(a, (win, win)).mean(axis=(-1, -2))

    n = win * win
    ux, uy = mean(x), mean(y)
    vx = n / (n - 1) * (mean(x * x) - ux * ux)
    vy = n / (n - 1) * (mean(y * y) - uy * uy)
    vxy = n / (n - 1) * (mean(x * y) - ux * uy)
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    s = (2 * ux * uy + c1) * (2 * vxy + c2) / ((ux * ux + uy * uy + c1) * (vx + vy + c2))
    return float(s.mean())


def test_matches_the_protocols_definition():
    rng = np.random.default_rng(7)
    gt = rng.random((3, 18, 40))
    pred = np.clip(gt + 0.2 * rng.standard_normal(gt.shape), 0, 1)
    pred[2] = rng.random((18, 40))                         # an unrelated image too
    got = ssim_images(pred, gt)
    want = np.array([ssim_twin(p, g) for p, g in zip(pred, gt)])
    assert got.dtype == np.float64 and got.shape == (3,)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    assert got[2] < 0.1 < got[0]                           # the noisy copy scores well above the stranger


def test_identical_images_score_one_and_order_does_not_matter():
    rng = np.random.default_rng(0)
    a, b = rng.random((2, 12, 30)), rng.random((2, 12, 30))
    np.testing.assert_allclose(ssim_images(a, a), 1.0, atol=1e-12)
    np.testing.assert_allclose(ssim_images(a, b), ssim_images(b, a), atol=1e-12)


def test_float32_inputs_are_scored_in_float64():
    rng = np.random.default_rng(1)
    a, b = rng.random((2, 12, 30)).astype(np.float32), rng.random((2, 12, 30)).astype(np.float32)
    np.testing.assert_array_equal(ssim_images(a, b), ssim_images(a.astype(np.float64), b.astype(np.float64)))


@pytest.mark.parametrize("pred_shape, gt_shape", [((2, 12, 30), (2, 12, 31)), ((2, 12, 30), (3, 12, 30)),
                                                   ((12, 30), (12, 30))])
def test_shape_mismatch_names_both_shapes(pred_shape, gt_shape):
    with pytest.raises(ImageError, match=r"pred .* and gt .* must both be \[K, H, W\]"):
        ssim_images(np.zeros(pred_shape), np.zeros(gt_shape))
