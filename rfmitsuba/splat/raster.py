"""Front-to-back compositing of projected Gaussians, with a hand-written backward.

For pixel p (column j, row i, in pixel units ``(j, i)``) and the Gaussians of
its tile list sorted by distance from the receiver:

    du = wrap(j - u_k) into [-W/2, W/2)      (azimuth wraps at 0/360 deg)
    dv = i - v_k
    q_k = a du^2 + 2 b du dv + c dv^2        (conic = inverse 2D covariance)
    alpha_k = min(ALPHA_MAX, opacity_k * exp(-q_k / 2)); skipped if < ALPHA_MIN
    T_k = prod_{l<k, kept} (1 - alpha_l)
    I(p) = sum_{k kept} T_k alpha_k s_k

The azimuth offset is taken to the nearest copy of the centre, so a Gaussian
wider than half the azimuth circle (close to the zenith or to the receiver)
is cut at the azimuth opposite its centre; with a tilted footprint (non-zero
``b``) the image has a small step there. Gradients are those of this
definition (the step itself has none).

One lane per pixel, lanes ordered tile by tile, so the 16 lanes of an
AVX-512 packet share one tile list. The forward pass is a symbolic
``dr.while_loop``; the backward pass (``dr.CustomOp``) walks the same list back
to front, recovering ``T_k = T_{k+1} / (1 - alpha_k)`` from the final
transmittance as 3DGS does, and scatter-adds per-pair gradients of
(u, v, a, b, c, opacity, signal) with ``ReduceMode.Local`` (the lanes of a
packet hit the same Gaussian at the same step, so one atomic per packet).
"""
from __future__ import annotations

import drjit as dr
import numpy as np

from .. import backend as B
from . import tiles as _tiles
from .tiles import ALPHA_MAX, ALPHA_MIN, TILE_H, TILE_SIZE, TILE_W

#: Scatter mode of the backward pass (see module docstring).
GRAD_MODE = dr.ReduceMode.Local


def _lanes(views: int, height: int, width: int):
    """Per-lane tile index, pixel row/column, image index and activity."""
    nty, ntx = _tiles.tile_grid(height, width)
    lanes = dr.arange(B.UInt32, views * nty * ntx * TILE_SIZE)
    tile = lanes // TILE_SIZE
    k = lanes - tile * TILE_SIZE
    tiles_per_view = nty * ntx
    view = tile // tiles_per_view
    t = tile - view * tiles_per_view
    ty = t // ntx
    tx = t - ty * ntx
    row = ty * TILE_H + k // TILE_W
    col = tx * TILE_W + (k - (k // TILE_W) * TILE_W)
    active = (row < height) & (col < width)
    pix = view * (height * width) + row * width + col
    return tile, B.Float(row), B.Float(col), pix, active


def _alpha(params, g, px, py, width):
    u, v, ca, cb, cc, op, sig = (dr.gather(B.Float, p, g) for p in params)
    du = px - u
    du = dr.select(du >= 0.5 * width, du - width, du)
    du = dr.select(du < -0.5 * width, du + width, du)
    dv = py - v
    q = ca * du * du + 2.0 * cb * du * dv + cc * dv * dv
    gauss = dr.exp(-0.5 * q)
    raw = op * gauss
    alpha = dr.minimum(raw, ALPHA_MAX)
    return alpha, raw, gauss, du, dv, ca, cb, cc, sig


class Rasterize(dr.CustomOp):
    """``dr.custom(Rasterize, u, v, a, b, c, opacity, signal, lists, views, height, width)``
    -> Float [B*H*W], images row-major (view, row, column)."""

    def eval(self, u, v, ca, cb, cc, op, sig, lists, views, height, width):
        self.params = (u, v, ca, cb, cc, op, sig)
        self.shape = (views, height, width)
        self.entries = B.UInt32(lists.entries) if lists.entries.size else B.UInt32(0)
        self.offsets = B.UInt32(lists.offsets)
        tile, py, px, pix, active = _lanes(views, height, width)
        start = dr.gather(B.UInt32, self.offsets, tile)
        end = dr.gather(B.UInt32, self.offsets, tile + 1)
        end = dr.select(active, end, start)

        def body(i, T, C):
            g = dr.gather(B.UInt32, self.entries, i)
            alpha, _, _, _, _, _, _, _, s = _alpha(self.params, g, px, py, width)
            use = alpha >= ALPHA_MIN
            C = dr.select(use, dr.fma(T * alpha, s, C), C)
            T = dr.select(use, T * (1.0 - alpha), T)
            return i + 1, T, C

        _, T, C = dr.while_loop((start, B.Float(1.0), B.Float(0.0)),
                                lambda i, T, C: i < end, body, labels=("i", "T", "C"),
                                label="splat_forward")
        self.T_final = T
        image = dr.zeros(B.Float, views * height * width)
        dr.scatter(image, C, pix, active)
        dr.eval(image, T)
        return image

    def forward(self):
        raise NotImplementedError("splat rendering supports reverse-mode differentiation only")

    def backward(self):
        views, height, width = self.shape
        grad_img = self.grad_out()
        tile, py, px, pix, active = _lanes(views, height, width)
        start = dr.gather(B.UInt32, self.offsets, tile)
        end = dr.gather(B.UInt32, self.offsets, tile + 1)
        end = dr.select(active, end, start)
        gpix = dr.gather(B.Float, grad_img, pix, active)
        m = dr.width(self.params[0])
        grads = [dr.zeros(B.Float, m) for _ in range(7)]

        def body(i, T, acc):
            i = i - 1
            g = dr.gather(B.UInt32, self.entries, i)
            alpha, raw, gauss, du, dv, ca, cb, cc, s = _alpha(self.params, g, px, py, width)
            use = alpha >= ALPHA_MIN
            one_m = 1.0 - alpha
            T_k = T / one_m
            w = T_k * alpha
            g_s = gpix * w
            g_alpha = gpix * (T_k * s - acc / one_m)
            free = raw < ALPHA_MAX  # not clamped: alpha depends on opacity and q
            g_alpha = dr.select(free, g_alpha, 0.0)
            g_op = g_alpha * gauss
            g_q = -0.5 * g_alpha * alpha
            # dq/du_centre = -(2a du + 2b dv); dq/dv_centre = -(2b du + 2c dv)
            g_u = -g_q * 2.0 * (ca * du + cb * dv)
            g_v = -g_q * 2.0 * (cb * du + cc * dv)
            vals = (g_u, g_v, g_q * du * du, g_q * 2.0 * du * dv, g_q * dv * dv, g_op, g_s)
            for target, val in zip(grads, vals):
                dr.scatter_reduce(dr.ReduceOp.Add, target, val, g, use, mode=GRAD_MODE)
            acc = dr.select(use, dr.fma(w, s, acc), acc)
            T = dr.select(use, T_k, T)
            return i, T, acc

        dr.while_loop((end, self.T_final, B.Float(0.0)), lambda i, T, acc: i > start, body,
                      labels=("i", "T", "acc"), label="splat_backward")
        names = ("u", "v", "ca", "cb", "cc", "op", "sig")
        for name, gr in zip(names, grads):
            self.set_grad_in(name, gr)

    def name(self):
        return "splat.Rasterize"


def rasterize(proj, *, views: int, height: int, width: int):
    """Composite projected Gaussians into images.

    Args:
        proj: :class:`rfmitsuba.splat.project.Projected`, fields of size B*N.
        views, height, width: B and the image size, pixels.

    Returns:
        Float [B*H*W], row-major images, differentiable (reverse mode) in
        ``proj.u, v, conic_*, opacity, signal``.
    """
    dr.eval(proj.u, proj.v, proj.conic_a, proj.conic_b, proj.conic_c, proj.cov_uu, proj.cov_vv,
            proj.opacity, proj.signal, proj.depth)  # one kernel for the whole projection
    fields = [dr.detach(x) for x in (proj.u, proj.v, proj.cov_uu, proj.cov_vv, proj.opacity, proj.depth)]
    host = [np.asarray(x.numpy(), dtype=np.float32) for x in fields]
    lists = _tiles.build(*host, views=views, height=height, width=width)
    return dr.custom(Rasterize, proj.u, proj.v, proj.conic_a, proj.conic_b, proj.conic_c,
                     proj.opacity, proj.signal, lists, views, height, width)
