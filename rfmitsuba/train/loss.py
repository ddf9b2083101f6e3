"""Structural similarity (SSIM) in Dr.Jit, and the training loss.

:func:`ssim` reproduces ``skimage.metrics.structural_similarity(pred, gt,
data_range=1.0)`` for 2D images with its defaults: a 7x7 uniform window,
``K1 = 0.01``, ``K2 = 0.03``, sample covariance (``49/48``), and the mean of the
SSIM map over the image cropped by 3 pixels on each side. The crop removes
every position whose window touches the border, so skimage's reflective
padding never enters: the map is computed on "valid" 7x7 windows only, by
two separable box sums (gathers; a ``dr.CustomOp`` whose adjoint is again a
box sum, so the backward pass needs no atomic scatter-additions).

:func:`loss` is the training loss ``0.8 * L1 + 0.2 * (1 - SSIM)`` (paper,
Section "Model Training"), averaged over a batch [B, H, W].
:func:`rfmitsuba.core.ssim.ssim_images` is the metric protocol itself (skimage, float64).
"""
from __future__ import annotations

import drjit as dr
import numpy as np

from ..core import backend as B
from ..core.errors import ImageError
from ..core.ssim import WINDOW

#: Window side [px]: the metric protocol's (:data:`rfmitsuba.core.ssim.WINDOW`), so the loss and the
#: metric cannot drift apart. The constants are skimage's defaults.
WIN = WINDOW
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


#: Positions per lane of :class:`_BoxSum`'s passes. A lane keeps its window's values in
#: registers as it slides: one load per sum instead of seven, each sum added in the same order as
#: a sum of seven loads, so the same bits. The loss's kernels (kernel history, medians of 50
#: calls alternating with seven loads per sum in one process), 4 x 90 x 360: forward 2.1-2.6 ->
#: 1.3-1.9 ms, backward 1.3-1.8 -> 0.9-1.5 ms; 8 x 45 x 180: forward 1.2-1.3 -> 0.8 ms, backward
#: 0.81-0.85 -> 0.65-0.67 ms (16 positions per lane: the forward alike, the backward 0.80-1.04 of
#: the old time).
SEGMENT = 8


def _segments(outer, count, inner):
    """Lanes that slide along the middle axis of [outer, count, inner] positions, up to
    :data:`SEGMENT` each: per lane its (o, first position, c) and how many positions it takes."""
    segs = -(-count // SEGMENT)
    k = dr.arange(B.UInt32, outer * segs * inner)
    rest = k // inner
    c = k - rest * inner
    o = rest // segs
    first = (rest - o * segs) * SEGMENT
    return o, first, c, dr.minimum(count - first, SEGMENT)


class _BoxSum(dr.CustomOp):
    """Sums over 7 consecutive elements along one axis of several arrays at once (a list ``xs``).

    Each input is a flat Float holding [outer, length, inner] (row-major); the
    output holds [outer, length - 6, inner]. The adjoint is again a box sum
    (over the gradient, clipped at the ends), so both passes are gathers with
    no atomic scatter-additions. Both slide a window along the axis, :data:`SEGMENT`
    positions per lane.
    """

    def eval(self, xs, outer, length, inner):
        self.dims = (outer, length, inner)
        lo = length - WIN + 1
        o, first, c, steps = _segments(outer, lo, inner)
        src = (o * length + first) * inner + c       # the lane's first window starts here
        dst = (o * lo + first) * inner + c
        out = [dr.empty(B.Float, outer * lo * inner) for _ in xs]
        # the window's first six values; each step loads the seventh, writes the sum, drops the first
        win = tuple(tuple(dr.gather(B.Float, x, src + d * inner) for d in range(WIN - 1)) for x in xs)

        def body(j, win):
            at = j * inner
            nxt = []
            for x, y, w in zip(xs, out, win):
                w = w + (dr.gather(B.Float, x, src + at + (WIN - 1) * inner),)
                dr.scatter(y, sum(w), dst + at)
                nxt.append(w[1:])
            return j + 1, tuple(nxt)

        dr.while_loop((dr.zeros(B.UInt32, dr.width(src)), win), lambda j, win: j < steps, body,
                      labels=("j", "win"), label="ssim_box")
        dr.eval(out)   # one kernel for all the sums
        return out

    def forward(self):
        raise NotImplementedError("SSIM supports reverse-mode differentiation only")

    def backward(self):
        outer, length, inner = self.dims
        lo = length - WIN + 1
        grads = self.grad_out()
        dr.eval(grads)  # one kernel for all the incoming gradients
        # Input position i gets the output gradients at positions i, i - 1, ..., i - 6 (those in
        # [0, lo)), added in that order. Each lane slides along up to SEGMENT input positions,
        # with the window's last six gradients in registers: one load per position.
        o, first, c, steps = _segments(outer, length, inner)
        dst = (o * length + first) * inner + c
        src = o * (lo * inner) + c - (WIN - 1) * inner   # output position p at src + (p + 6) * inner

        def at(g, shifted):                              # the gradient at p = shifted - 6, or 0
            ok = (shifted >= WIN - 1) & (shifted < lo + WIN - 1)
            return dr.gather(B.Float, g, src + shifted * inner, ok)

        totals = [dr.empty(B.Float, outer * length * inner) for _ in grads]
        win = tuple(tuple(at(g, first + d) for d in range(WIN - 1)) for g in grads)   # p = i-6 .. i-1

        def body(j, win):
            nxt = []
            for g, t, w in zip(grads, totals, win):
                w = w + (at(g, first + j + (WIN - 1)),)                            # p = i enters
                dr.scatter(t, sum(reversed(w)), dst + j * inner)
                nxt.append(w[1:])
            return j + 1, tuple(nxt)

        dr.while_loop((dr.zeros(B.UInt32, dr.width(src)), win), lambda j, win: j < steps, body,
                      labels=("j", "win"), label="ssim_box_adjoint")
        dr.eval(totals)  # one kernel for all of them
        self.set_grad_in("xs", totals)

    def name(self):
        return "ssim.BoxSum"


def _box(values, views, height, width):
    """Sums over every valid 7x7 window: Float [B*H*W] -> Float [B*(H-6)*(W-6)]."""
    h = dr.custom(_BoxSum, list(values), views * height, width, 1)  # along rows
    return dr.custom(_BoxSum, h, views, height, width - WIN + 1)  # along columns


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
    if dr.grad_enabled(y):
        sx, sy, sxx, syy, sxy = _box([xs, ys, xs * xs, ys * ys, xs * ys], views, height, width)
    else:  # the usual case, a fixed target: its sums need no adjoint (3 of 5 arrays go backward)
        sx, sxx, sxy = _box([xs, xs * xs, xs * ys], views, height, width)
        with dr.suspend_grad():
            sy, syy = _box([ys, ys * ys], views, height, width)
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
    # Means as sums times opaque reciprocals: a literal 1/size would be compiled
    # into the kernels, and a different batch size would recompile them.
    inv_pixels = dr.opaque(B.Float, 1.0 / dr.width(x))
    inv_views = dr.opaque(B.Float, 1.0 / shape[0])
    l1 = dr.sum(dr.abs(x - y)) * inv_pixels
    return (1.0 - LAMBDA) * l1 + LAMBDA * (1.0 - dr.sum(ssim(pred, gt)) * inv_views)
