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

Layout: one packet of lanes per 8x8 tile (:func:`tiles.lanes_per_tile`: 16
lanes of four pixels of one column with AVX-512, 8 lanes of eight with AVX2),
so all lanes of a packet walk the same tile list and a Gaussian's seven
parameters come with two 4-wide packet loads per step.
Tiles are visited in a scrambled order so that the two equal lane blocks
Dr.Jit gives its threads hold a similar amount of work.

Forward: a symbolic ``dr.while_loop`` over the tile list (one kernel).
Backward (``dr.CustomOp``): the same list back to front, recovering
``T_k = T_{k+1} / (1 - alpha_k)`` from the final transmittance as 3DGS does;
each step sums the gradients of (u, v, a, b, c, opacity, signal) over the
lane's four pixels and scatter-adds them with ``ReduceMode.Local`` (one
packet reduction and one uncontended atomic) into a slot of *that pair* --
a slot belongs to one tile, so threads never fight over it. A second loop
(one lane per Gaussian) then sums each Gaussian's pair slots. No kernel
contains N, the number of pairs or any other size: densification does not
recompile.
"""
from __future__ import annotations

import drjit as dr

from ..core import backend as B
from . import tiles as _tiles
from .tiles import ALPHA_MAX, ALPHA_MIN, TILE_H, TILE_SIZE, TILE_W

#: Scatter mode of the backward pass (see module docstring).
GRAD_MODE = dr.ReduceMode.Local
#: Primes for the tile scrambling (the first one not dividing the tile count is used).
_STRIDES = (37, 41, 43)  # small: slot * stride stays far below 2^32


def _lanes(views: int, height: int, width: int, tile_lanes: int):
    """Per lane (``tile_lanes`` per tile): tile index, and per sub-pixel q < TILE_SIZE /
    tile_lanes: pixel row (Float), image index (UInt32) and activity; plus the pixel column
    (Float) and 'any active'."""
    sub, sub_step = TILE_SIZE // tile_lanes, tile_lanes // TILE_W  # pixels per lane, rows between them
    nty, ntx = _tiles.tile_grid(height, width)
    num_tiles = views * nty * ntx
    lanes = dr.arange(B.UInt32, num_tiles * tile_lanes)
    slot = lanes // tile_lanes
    k = lanes - slot * tile_lanes
    # Tiles in a scrambled order (slot * stride mod T, a permutation), so that the
    # contiguous lane blocks Dr.Jit hands to its threads mix busy and idle tiles.
    stride = next((p for p in _STRIDES if num_tiles % p), 1)
    tile = (slot * dr.opaque(B.UInt32, stride)) % dr.opaque(B.UInt32, num_tiles)
    tiles_per_view = nty * ntx
    view = tile // tiles_per_view
    t = tile - view * tiles_per_view
    ty = t // ntx
    tx = t - ty * ntx
    lane_row = k // TILE_W
    col = tx * TILE_W + (k - lane_row * TILE_W)
    rows, pix, active = [], [], []
    for q in range(sub):
        row = ty * TILE_H + lane_row + q * sub_step
        rows.append(B.Float(row))
        active.append((row < height) & (col < width))
        pix.append(view * (height * width) + row * width + col)
    any_active = active[0]
    for a in active[1:]:
        any_active |= a
    return tile, rows, B.Float(col), pix, active, any_active


def _pack(params):
    """7 Float [M] -> one Float [8*M], entry-major, so a loop step reads one
    entry's parameters with two aligned 4-wide packet loads."""
    m = dr.width(params[0])
    packed = dr.zeros(B.Float, 8 * m)
    idx = dr.arange(B.UInt32, m) * 8
    for c, p in enumerate(params):
        dr.scatter(packed, p, idx + c)
    dr.eval(packed)
    return packed


def _load(packed, g):
    lo = dr.gather(B.Array4f, packed, 2 * g)
    hi = dr.gather(B.Array4f, packed, 2 * g + 1)
    return lo[0], lo[1], lo[2], lo[3], hi[0], hi[1], hi[2]  # u, v, a, b, c, opacity, signal


def _alpha(par, px, py, width):
    u, v, ca, cb, cc, op, _ = par
    du = px - u
    du = dr.select(du >= 0.5 * width, du - width, du)
    du = dr.select(du < -0.5 * width, du + width, du)
    dv = py - v
    q = ca * du * du + 2.0 * cb * du * dv + cc * dv * dv
    gauss = dr.exp(-0.5 * q)
    raw = op * gauss
    alpha = dr.minimum(raw, ALPHA_MAX)
    return alpha, raw, gauss, du, dv


class Rasterize(dr.CustomOp):
    """``dr.custom(Rasterize, u, v, a, b, c, opacity, signal, lists, views, height, width, tile_lanes)``
    -> Float [B*H*W], images row-major (view, row, column)."""

    def eval(self, u, v, ca, cb, cc, op, sig, lists, views, height, width, tile_lanes):
        self.params = (u, v, ca, cb, cc, op, sig)
        self.packed = _pack(self.params)
        self.shape = (views, height, width, tile_lanes)
        self.lists = lists
        tile, rows, px, pix, active, any_active = _lanes(views, height, width, tile_lanes)
        sub = len(rows)
        start = dr.gather(B.UInt32, lists.offsets, tile)
        end = dr.select(any_active, dr.gather(B.UInt32, lists.offsets, tile + 1), start)

        def body(i, T, C):
            par = _load(self.packed, dr.gather(B.UInt32, lists.entries, i))
            s = par[6]
            T, C = list(T), list(C)
            for q in range(sub):
                alpha = _alpha(par, px, rows[q], width)[0]
                use = (alpha >= ALPHA_MIN) & active[q]
                C[q] = dr.select(use, dr.fma(T[q] * alpha, s, C[q]), C[q])
                T[q] = dr.select(use, T[q] * (1.0 - alpha), T[q])
            return i + 1, tuple(T), tuple(C)

        one = tuple(B.Float(1.0) for _ in range(sub))
        zero = tuple(B.Float(0.0) for _ in range(sub))
        _, T, C = dr.while_loop((start, one, zero), lambda i, T, C: i < end, body,
                                labels=("i", "T", "C"), label="splat_forward")
        self.T_final = T
        dr.eval(T, C)  # one kernel for the loop (each scatter below would otherwise re-run it)
        image = dr.zeros(B.Float, views * height * width)
        for q in range(sub):
            dr.scatter(image, C[q], pix[q], active[q])
        dr.eval(image)
        return image

    def forward(self):
        raise NotImplementedError("splat rendering supports reverse-mode differentiation only")

    def backward(self):
        views, height, width, tile_lanes = self.shape
        grad_img = self.grad_out()
        lists = self.lists
        tile, rows, px, pix, active, any_active = _lanes(views, height, width, tile_lanes)
        sub = len(rows)
        start = dr.gather(B.UInt32, lists.offsets, tile)
        end = dr.select(any_active, dr.gather(B.UInt32, lists.offsets, tile + 1), start)
        gpix = [dr.gather(B.Float, grad_img, pix[q], active[q]) for q in range(sub)]
        m = dr.width(self.params[0])
        # Per-pair gradient slots: a slot is written by one tile (one packet) only,
        # so the packet-local reduction's single atomic never contends.
        pair_grads = [dr.zeros(B.Float, max(lists.count, 1)) for _ in range(7)]

        def body(i, T, acc):
            i = i - 1
            par = _load(self.packed, dr.gather(B.UInt32, lists.entries, i))
            _, _, ca, cb, cc, _, s = par
            T, acc = list(T), list(acc)
            sums = [B.Float(0.0) for _ in range(7)]
            for q in range(sub):
                alpha, raw, gauss, du, dv = _alpha(par, px, rows[q], width)
                use = (alpha >= ALPHA_MIN) & active[q]
                inv_one_m = dr.rcp(1.0 - alpha)
                T_k = T[q] * inv_one_m
                w = T_k * alpha
                g_alpha = gpix[q] * (T_k * s - acc[q] * inv_one_m)
                g_alpha = dr.select(use & (raw < ALPHA_MAX), g_alpha, 0.0)  # clamped: no dependence
                g_q = -0.5 * g_alpha * alpha
                g_s = dr.select(use, gpix[q] * w, 0.0)
                # dq/du_centre = -(2a du + 2b dv); dq/dv_centre = -(2b du + 2c dv)
                vals = (-2.0 * g_q * (ca * du + cb * dv), -2.0 * g_q * (cb * du + cc * dv),
                        g_q * du * du, 2.0 * g_q * du * dv, g_q * dv * dv, g_alpha * gauss, g_s)
                sums = [a + b for a, b in zip(sums, vals)]
                acc[q] = dr.select(use, dr.fma(w, s, acc[q]), acc[q])
                T[q] = dr.select(use, T_k, T[q])
            for target, val in zip(pair_grads, sums):
                dr.scatter_reduce(dr.ReduceOp.Add, target, val, i, mode=GRAD_MODE)
            return i, tuple(T), tuple(acc)

        zero = tuple(B.Float(0.0) for _ in range(sub))
        dr.while_loop((end, tuple(self.T_final), zero), lambda i, T, acc: i > start, body,
                      labels=("i", "T", "acc"), label="splat_backward")
        dr.eval(pair_grads)
        grads = _sum_pairs(pair_grads, lists, m)
        names = ("u", "v", "ca", "cb", "cc", "op", "sig")
        for name, gr in zip(names, grads):
            self.set_grad_in(name, gr)

    def name(self):
        return "splat.Rasterize"


def _sum_pairs(pair_grads, lists, m):
    """Per-pair gradients (tile order) -> per-entry sums, Float [m] each, without atomics:
    one lane per entry walks its contiguous range of the entry-major pair order."""
    if lists.count == 0:
        return [dr.zeros(B.Float, m) for _ in pair_grads]
    first, length = lists.first, lists.length
    end = first + length

    def body(j, *acc):
        slot = dr.gather(B.UInt32, lists.sorted_pos, j)
        return (j + 1,) + tuple(a + dr.gather(B.Float, pg, slot) for a, pg in zip(acc, pair_grads))

    _, *sums = dr.while_loop((B.UInt32(first),) + tuple(B.Float(0.0) for _ in pair_grads),
                             lambda j, *acc: j < end, body, label="splat_pair_sums")
    out = [dr.zeros(B.Float, m) for _ in pair_grads]
    for o, v in zip(out, sums):
        dr.scatter(o, v, lists.order)  # order is a permutation of the entries
    dr.eval(out)
    return out


def rasterize(proj, *, views: int, height: int, width: int, tile_lanes: int | None = None):
    """Composite projected Gaussians into images.

    Args:
        proj: :class:`rfmitsuba.splat.project.Projected`, fields of size B*N.
        views, height, width: B and the image size, pixels.
        tile_lanes: lanes per 8x8 tile, one of ``TILE_LANE_CHOICES`` (default
            :func:`tiles.lanes_per_tile`, one packet of the backend); the image and its
            gradients do not depend on it (up to float32 summation order).

    Raises:
        ConfigError: ``tile_lanes`` is not one of ``TILE_LANE_CHOICES``.

    Returns:
        Float [B*H*W], row-major images, differentiable (reverse mode) in
        ``proj.u, v, conic_*, opacity, signal``.
    """
    tile_lanes = (_tiles.lanes_per_tile() if tile_lanes is None
                  else _tiles.checked_lanes(tile_lanes, what="tile_lanes"))
    dr.eval(proj.u, proj.v, proj.conic_a, proj.conic_b, proj.conic_c, proj.cov_uu, proj.cov_vv,
            proj.opacity, proj.signal, proj.depth)  # one kernel for the whole projection
    n = dr.width(proj.u) // views
    lists = _tiles.build(*(dr.detach(x) for x in (proj.u, proj.v, proj.cov_uu, proj.cov_vv,
                                                    proj.opacity, proj.depth)),
                         views=views, n=n, height=height, width=width)
    return dr.custom(Rasterize, proj.u, proj.v, proj.conic_a, proj.conic_b, proj.conic_c,
                     proj.opacity, proj.signal, lists, views, height, width, tile_lanes)
