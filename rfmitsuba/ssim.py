"""Structural similarity (SSIM) in Dr.Jit, and the training loss.

:func:`ssim` reproduces ``skimage.metrics.structural_similarity(pred, gt,
data_range=1.0)`` for 2D images with its defaults: a 7x7 uniform window,
``K1 = 0.01``, ``K2 = 0.03``, sample covariance (``49/48``), and the mean of the
SSIM map over the image cropped by 3 pixels on each side. The crop removes
every position whose window touches the border, so skimage's reflective
padding never enters: the map is computed on "valid" 7x7 windows only, by
two separable box sums (gathers, differentiable by Dr.Jit's AD).

:func:`loss` is the training loss ``0.8 * L1 + 0.2 * (1 - SSIM)`` (paper,
Section "Model Training"), averaged over a batch [B, H, W].
:func:`ssim_np` is the SPEC metric protocol itself (skimage, float64).
"""
from __future__ import annotations

import drjit as dr
import numpy as np

from . import backend as B
from .errors import ImageError

#: Window side, pixels, and the constants of skimage's defaults.
WIN = 7
K1, K2 = 0.01, 0.03
#: Weight of the SSIM term in the training loss (lambda in the paper).
LAMBDA = 0.2


def _flat(x, name):
    """TensorXf [B, H, W] or [H, W] (or numpy) -> (Float [B*H*W], (B, H, W))."""
    if not dr.is_tensor_v(x):
        x = B.TensorXf(np.asarray(x, dtype=np.float32))
    shape = tuple(x.shape)
    if len(shape) == 2:
        shape = (1,) + shape
    if len(shape) != 3:
        raise ImageError(f"{name}: expected shape [B, H, W] or [H, W], got {tuple(x.shape)}")
    return x.array, shape


def _box(values, views, height, width):
    """Sums over every valid 7x7 window: Float [B*H*W] -> Float [B*(H-6)*(W-6)]."""
    wo, ho = width - WIN + 1, height - WIN + 1
    # Horizontal pass: [B, H, W] -> [B, H, Wo].
    k = dr.arange(B.UInt32, views * height * wo)
    row = k // wo  # b*H + r
    col = k - row * wo
    base = row * width + col
    h = [sum(dr.gather(B.Float, v, base + d, mode=dr.ReduceMode.Direct) for d in range(WIN))
         for v in values]
    # Vertical pass: [B, H, Wo] -> [B, Ho, Wo].
    k = dr.arange(B.UInt32, views * ho * wo)
    plane = k // (ho * wo)
    rem = k - plane * (ho * wo)
    base = (plane * height) * wo + rem
    return [sum(dr.gather(B.Float, v, base + d * wo, mode=dr.ReduceMode.Direct) for d in range(WIN))
            for v in h]


def ssim(pred, gt):
    """Mean SSIM of each image pair (skimage defaults, data_range = 1).

    Args:
        pred, gt: TensorXf (or numpy) [B, H, W] or [H, W], values nominally in
            [0, 1]; H, W >= 7.

    Returns:
        Float [B], differentiable with respect to both inputs.
    """
    x, shape = _flat(pred, "pred")
    y, shape_gt = _flat(gt, "gt")
    if shape != shape_gt:
        raise ImageError(f"pred and gt differ in shape: {shape} vs {shape_gt}")
    views, height, width = shape
    if height < WIN or width < WIN:
        raise ImageError(f"SSIM needs images of at least {WIN}x{WIN} pixels, got {height}x{width}")
    # A constant shift leaves SSIM's variances unchanged and keeps float32 sums
    # of squares small (less cancellation in E[x^2] - E[x]^2).
    xs, ys = x - 0.5, y - 0.5
    sx, sy, sxx, syy, sxy = _box([xs, ys, xs * xs, ys * ys, xs * ys], views, height, width)
    n = float(WIN * WIN)
    mx, my = sx / n, sy / n
    norm = n / (n - 1.0)
    vx = norm * (sxx / n - mx * mx)
    vy = norm * (syy / n - my * my)
    vxy = norm * (sxy / n - mx * my)
    ux, uy = mx + 0.5, my + 0.5
    c1, c2 = K1 * K1, K2 * K2
    s = ((2.0 * ux * uy + c1) * (2.0 * vxy + c2)) / ((ux * ux + uy * uy + c1) * (vx + vy + c2))
    count = (height - WIN + 1) * (width - WIN + 1)
    return dr.block_sum(s, count) / count


def loss(pred, gt):
    """Training loss ``0.8 * mean|pred - gt| + 0.2 * (1 - mean SSIM)``.

    Args:
        pred, gt: TensorXf [B, H, W] (or [H, W]), normalised PAS.

    Returns:
        Float of size 1, differentiable.
    """
    x, shape = _flat(pred, "pred")
    y, shape_gt = _flat(gt, "gt")
    if shape != shape_gt:
        raise ImageError(f"pred and gt differ in shape: {shape} vs {shape_gt}")
    l1 = dr.mean(dr.abs(x - y))
    return (1.0 - LAMBDA) * l1 + LAMBDA * (1.0 - dr.mean(ssim(pred, gt)))


def ssim_np(pred, gt) -> np.ndarray | float:
    """The SPEC metric: skimage SSIM (data_range = 1) per image, float64.

    Args:
        pred, gt: numpy [B, H, W] or [H, W].

    Returns:
        float64 [B] (or a float for one [H, W] pair).
    """
    from skimage.metrics import structural_similarity

    p = np.asarray(pred, dtype=np.float64)
    g = np.asarray(gt, dtype=np.float64)
    if p.shape != g.shape or p.ndim not in (2, 3):
        raise ImageError(f"pred and gt must both be [B, H, W] or [H, W]; got {p.shape} and {g.shape}")
    if p.ndim == 2:
        return float(structural_similarity(p, g, data_range=1.0))
    return np.array([structural_similarity(a, b, data_range=1.0) for a, b in zip(p, g)])
