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

Layout: 8 lanes per 8x8 tile on the LLVM backend, each drawing eight pixels
of one column (:func:`tiles.lanes_per_tile`; an AVX-512 packet holds two
tiles, an AVX2 packet one), so the lanes of a tile walk its list together in
one packet. Before the loops, each pair
(tile, Gaussian) gets its own record of eight floats in tile-list order
(:func:`_pair_records`: centre, conic scaled to base 2, opacity, signal), so a
loop step reads its Gaussian with one aligned 8-wide packet load per lane and
no indirection through the list's entry index; ``exp(-q/2)`` is evaluated as
``2^x`` by :func:`_exp2`.
Each view's tiles are ranked by list length and taken two by two, so the two
tiles of a packet have lists of about equal length, and the pairs are dealt in
turn to the two equal lane blocks Dr.Jit gives its threads, view after view
(:func:`_slot_tiles`, :func:`_lanes`).

Forward: a symbolic ``dr.while_loop`` over the tile list (one kernel).
Backward (``dr.CustomOp``): the same list back to front, recovering
``T_k = T_{k+1} / (1 - alpha_k)`` from the final transmittance as 3DGS does.
Each step sums, over the lane's pixels, seven moments of the pair
(with ``e = dL/dalpha * exp(-q/2)``: ``e, e du, e dv, e du^2, e du dv, e dv^2``
and ``dL/dsignal``; a lane's pixels share one column, so ``du``, and the
pixels sum ``e, e dv, e dv^2`` and ``dL/dsignal`` only, the ``du`` factors
applied once per lane) and adds them, one 8-wide packet per lane, into its
Gaussian's (entry's) accumulator; the entry index travels in the pair record's
last float. On the LLVM backend the addition goes into a copy of the
accumulators per thread (``ReduceMode.Expand``, chosen by ``Auto`` below
Dr.Jit's expand threshold, :func:`_moment_mode`), lane by lane without
atomics, and the copies are added after the kernel; on CUDA it is a warp
reduction and an atomic addition. The gradients of (u, v, a, b, c,
opacity, signal) are linear in the moments with the Gaussian's own conic and
opacity as coefficients (:func:`_moments_to_grads`), formed once per entry. No
kernel contains N, the number of pairs or any other size: densification does
not recompile.

Summation order: a thread adds in lane order, a lane in list order (back to
front); so the gradients depend on the tile lists and on the number of Dr.Jit
threads at the level of float32 rounding (culled lists: within 1e-5 relative),
and a run repeated on the same machine gives the same bits. Before 2026-11-28
each pair had its own slot and a second loop summed every entry's slots; that
kept the bits under culling but cost a per-entry walk whose packets waited for
their longest list, an inverse permutation of the pairs and a 10 MB memset:
build + forward + backward at 4 views of 90 x 360 and 10 000 Gaussians, 49.0
against 45.4 ms (median of 56 calls alternating in one process).
"""
from __future__ import annotations

import drjit as dr

from ..core import backend as B
from . import tiles as _tiles
from .tiles import ALPHA_MAX, ALPHA_MIN, TILE_H, TILE_SIZE, TILE_W

#: List-length levels of the tile sort of :func:`_slot_tiles` (longer lists tie at the last level).
_LENGTH_LEVELS = 4096
#: Up to this many tiles per view :func:`_slot_tiles` ranks the tiles by a loop over the view's
#: tiles (exact lengths), beyond by a sort
_RANK_LOOP_MAX = 2048


def _first_half_tiles(tiles_per_view: int) -> int:
    """Tiles of an even-numbered view that :func:`_slot_tiles` gives the first half of the lanes
    (an odd-numbered view gives it the others): those of the pairs 0, 3, 4, 7, 8, ... (pair p
    holds tiles 2p and 2p + 1 of the view's sorted order; an odd count leaves the last pair one
    tile)."""
    pairs = -(-tiles_per_view // 2)
    return sum(min(2, tiles_per_view - 2 * p) for p in range(pairs) if p % 4 in (0, 3))


def _slot_tiles(offsets, views: int, tiles_per_view: int):
    """The order in which the lanes take the tiles: slot -> tile, UInt32 [views * tiles_per_view].

    A packet of the LLVM backend holds two tiles (16 lanes on AVX-512, 8 per tile; a CUDA warp
    holds two tiles of 16), and it walks as many list steps as the longer of the two lists. So
    each view's tiles are ranked by list length (ties by tile index) and packed two by two in
    that order. The pairs go to the two halves of the lanes in turn, in snake order
    (pairs 0, 3, 4, 7, ... to the first half, to the second in odd-numbered views): Dr.Jit hands
    the two halves to its two threads, which get about the same work. Each half holds the views
    one after the other, so the backward pass's accumulators of one view at a time stay in the
    core's cache (against the whole batch mixed: backward 16.8-17.5 against 16.1-16.3 ms at
    4 x 10 000).

    Up to :data:`_RANK_LOOP_MAX` tiles per view, a tile's rank comes from a loop over its view's
    tiles (a kernel that no host call waits for); a sort would make the host wait for the tile
    lists before it traces the rasteriser (Stage-1 splat step, alternating pairs of steps in one
    run: median 57.4-58.3 against 58.8 ms). Beyond, the loop's quadratic cost would show, and
    the tiles are sorted (a stable counting sort, ``dr.detail.block_mkperm``; lengths from
    :data:`_LENGTH_LEVELS` on tie).

    At 4 views of 90 x 360 after 12 training steps of ``rfmitsuba bench splat``'s scene, a
    packet's two tiles had 36% more list steps than their mean in the previous order (each view's
    tiles in a fixed scrambled order) and 0.2% more sorted: forward 12.7 -> 10.7 ms, backward
    23.1 -> 20.7 ms (medians of 46 calls alternating in one process)."""
    UInt32 = B.UInt32
    num = views * tiles_per_view
    t = dr.arange(UInt32, num)
    length = dr.gather(UInt32, offsets, t + 1) - dr.gather(UInt32, offsets, t)
    tpv = dr.opaque(UInt32, tiles_per_view)
    view = t // tpv
    if tiles_per_view <= _RANK_LOOP_MAX:
        # each tile's rank in its view by (length, tile), counted over the view's tiles: lazy, so
        # the host does not wait for the tile lists here (a sort would evaluate its keys)
        dr.eval(length)
        first_of_view = view * tpv

        def count(j, r):
            s = first_of_view + j
            ls = dr.gather(UInt32, length, s)
            return j + 1, r + dr.select((ls < length) | ((ls == length) & (s < t)), 1, 0)

        _, r = dr.while_loop((UInt32(0), UInt32(0)), lambda j, r: j < tpv, count, labels=("j", "r"),
                             label="splat_tile_rank")
        order = t
    else:
        key = view * _LENGTH_LEVELS + dr.minimum(length, _LENGTH_LEVELS - 1)
        order = dr.detail.block_mkperm(key, num, 1 << max(int(views * _LENGTH_LEVELS - 1).bit_length(), 1))
        # sorted position t holds tile order[t]: its rank r in its view
        r = t - view * tpv
    p, e = r >> 1, r & 1
    m = p & 3
    odd = (view & 1) == 1
    second = ((m == 1) | (m == 2)) ^ odd
    first = _first_half_tiles(tiles_per_view)
    rest = tiles_per_view - first
    half0 = (views + 1) // 2 * first + views // 2 * rest      # tiles in the first half
    before = (view >> 1) * tpv                                  # of the view pairs before
    base = dr.select(second, half0 + before + dr.select(odd, rest, 0),
                     before + dr.select(odd, first, 0))
    slot = base + 2 * (2 * (p >> 2) + (m >> 1)) + e             # pairs 4c, 4c + 3 (or 4c + 1, 4c + 2)
    slot_tile = dr.empty(UInt32, num)
    dr.scatter(slot_tile, order, slot)
    return slot_tile


def _lanes(slot_tile, views: int, height: int, width: int, tile_lanes: int):
    """Per lane (``tile_lanes`` per tile, the tiles in the order ``slot_tile`` of
    :func:`_slot_tiles`): tile index, and per sub-pixel q < TILE_SIZE / tile_lanes: pixel row
    (Float), image index (UInt32) and activity; plus the pixel column (Float) and 'any active'."""
    sub, sub_step = TILE_SIZE // tile_lanes, tile_lanes // TILE_W  # pixels per lane, rows between them
    nty, ntx = _tiles.tile_grid(height, width)
    num_tiles = views * nty * ntx
    lanes = dr.arange(B.UInt32, num_tiles * tile_lanes)
    slot = lanes // tile_lanes
    k = lanes - slot * tile_lanes
    tiles_per_view = nty * ntx
    tile = dr.gather(B.UInt32, slot_tile, slot)
    view = tile // dr.opaque(B.UInt32, tiles_per_view)
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


#: Floats per pair record and per entry accumulator of the backward pass (one packet load or add).
RECORD = 8


#: log2(e): the pair records hold the conic in base 2, ``exp(-q/2) = 2^(-q log2(e) / 2)``.
LOG2E = 1.4426950408889634
#: Coefficients (constant term first) of the degree-5 polynomial for ``2^f`` on [-1/2, 1/2]
#: in :func:`_exp2`, fitted for relative error with the constant term held at 1, so ``2^n`` is
#: exact (9.1e-8 in float64; 1.6e-7 evaluated in float32, against 9.6e-8 for degree 6, whose
#: extra multiply-add per pixel cost 0.3-0.4 ms of the forward pass and 1.1-1.6 ms of the
#: backward at 4 views of 90 x 360, 10 000 Gaussians).
_EXP2_POLY = (1.0, 0.6931469775872211, 0.24022242085843495, 0.05550733773788456, 0.00967151263844277,
              0.001326471434949717)


def _exp2(x):
    """``2^x`` for Float x, relative error below 2.5e-7 for x in [-126, 127]; x is clamped to that
    range (below it ``2^-126``, a value the rasteriser treats as zero, above it ``2^127``).

    Range reduction ``x = n + f`` (n the nearest integer, ``|f| <= 1/2``, exact), a polynomial for
    ``2^f`` and the exponent ``n`` written into the float's exponent bits: 14 vector operations,
    where ``dr.exp`` takes about 24 with its overflow and underflow tests (its exponentials were
    31% of the rasteriser's forward time and 22% of the backward's)."""
    x = dr.clip(x, -126.0, 127.0)
    n = dr.round(x)
    f = x - n
    p = B.Float(_EXP2_POLY[-1])
    for c in _EXP2_POLY[-2::-1]:
        p = dr.fma(p, f, c)
    scale = dr.reinterpret_array(B.Float, (B.Int32(n) + 127) << 23)
    return p * scale


def _pair_records(params, lists):
    """Per pair, in tile-list order: ``u, v, -a k, -2b k, -c k, opacity, signal, entry`` of its
    entry with ``k = log2(e) / 2``, so that ``exp(-q/2) = 2^((-a k) du^2 + (-2b k) du dv + (-c k)
    dv^2)``, and the entry's index (UInt32 bits in a float): Float [8 * P] (P = ``lists.count``;
    one dummy record when there are none)."""
    u, v, ca, cb, cc, op, sig = params
    if lists.count == 0:
        return dr.zeros(B.Float, RECORD)
    m = dr.width(u)
    k = 0.5 * LOG2E
    # Each entry's record once (Float [8 M]), then one packet per pair: two packet copies are
    # cheaper than seven gathers per pair.
    per_entry = dr.empty(B.Float, RECORD * m)
    index = dr.arange(B.UInt32, m)
    dr.scatter(per_entry, B.jit.ArrayXf([u, v, -k * ca, -2.0 * k * cb, -k * cc, op, sig,
                                         dr.reinterpret_array(B.Float, index)]), index)
    records = dr.empty(B.Float, RECORD * lists.count)
    dr.scatter(records, dr.gather(B.jit.ArrayXf, per_entry, lists.entries, shape=(RECORD, lists.count)),
               dr.arange(B.UInt32, lists.count))
    dr.eval(records)
    return records


def _load(records, i, *, entry: bool = False):
    """The pair record i (see :func:`_pair_records`), one 8-wide packet gather; with ``entry``
    also the pair's entry index (UInt32)."""
    r = dr.gather(B.jit.ArrayXf, records, i, shape=(RECORD, dr.width(i)))
    par = (r[0], r[1], r[2], r[3], r[4], r[5], r[6])
    return (par, dr.reinterpret_array(B.UInt32, r[7])) if entry else par


def _alpha(par, px, py, width):
    u, v, qa, qb, qc, op, _ = par
    du = _tiles.wrap_offset(px - u, width)
    dv = py - v
    # exp(-q/2), q = a du^2 + dv (2b du + c dv) in base 2: a lane's pixels share du (one column),
    # so the du terms are computed once per lane and each pixel takes two fused multiply-adds
    gauss = _exp2(dr.fma(dv, dr.fma(qc, dv, qb * du), qa * du * du))
    raw = op * gauss
    alpha = dr.minimum(raw, ALPHA_MAX)
    return alpha, raw, gauss, du, dv


def _moment_mode():
    """Scatter mode of the backward pass's per-entry moment sums.

    LLVM: ``Auto``, which is ``Expand`` (a copy of the accumulators per thread, filled lane by
    lane without atomics and added after the kernel; the lanes of a packet may add to one entry,
    and so may both threads) while the accumulators hold at most :func:`drjit.expand_threshold`
    floats (a million by default: 31 250 views x Gaussians, 8 floats each), and atomic additions
    beyond, so that a many-core CPU does not hold a copy per core of a large array. CUDA:
    ``Local`` (a warp reduction of equal indices, then an atomic addition)."""
    return dr.ReduceMode.Local if B.is_cuda() else dr.ReduceMode.Auto


class Rasterize(dr.CustomOp):
    """``dr.custom(Rasterize, u, v, a, b, c, opacity, signal, lists, views, height, width, tile_lanes)``
    -> Float [B*H*W], images row-major (view, row, column)."""

    def eval(self, u, v, ca, cb, cc, op, sig, lists, views, height, width, tile_lanes):
        self.params = (u, v, ca, cb, cc, op, sig)
        self.records = _pair_records(self.params, lists)
        self.shape = (views, height, width, tile_lanes)
        self.lists = lists
        nty, ntx = _tiles.tile_grid(height, width)
        self.slot_tile = _slot_tiles(lists.offsets, views, nty * ntx)
        tile, rows, px, pix, active, any_active = _lanes(self.slot_tile, views, height, width, tile_lanes)
        sub = len(rows)
        start = dr.gather(B.UInt32, lists.offsets, tile)
        end = dr.select(any_active, dr.gather(B.UInt32, lists.offsets, tile + 1), start)

        def body(i, T, C):
            par = _load(self.records, i)
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
        image = dr.empty(B.Float, views * height * width)   # every pixel is one lane's (no memset)
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
        tile, rows, px, pix, active, any_active = _lanes(self.slot_tile, views, height, width, tile_lanes)
        sub = len(rows)
        start = dr.gather(B.UInt32, lists.offsets, tile)
        end = dr.select(any_active, dr.gather(B.UInt32, lists.offsets, tile + 1), start)
        gpix = [dr.gather(B.Float, grad_img, pix[q], active[q]) for q in range(sub)]
        m = dr.width(self.params[0])
        # per entry: its seven moments and a pad, summed over its pairs (see _moment_mode)
        moments = dr.zeros(B.Float, RECORD * m)
        mode = _moment_mode()

        def body(i, T, acc):
            i = i - 1
            par, entry = _load(self.records, i, entry=True)
            s = par[6]
            T, acc = list(T), list(acc)
            # per lane: sums over its pixels of e, e dv, e dv^2 and dL/dsignal; a lane's pixels
            # share du (one column), so the moments with du are these sums times du after the loop
            sums = [B.Float(0.0) for _ in range(4)]
            for q in range(sub):
                alpha, raw, gauss, du, dv = _alpha(par, px, rows[q], width)
                use = (alpha >= ALPHA_MIN) & active[q]
                inv_one_m = dr.rcp(1.0 - alpha)
                T_k = T[q] * inv_one_m
                w = T_k * alpha
                g_alpha = gpix[q] * (T_k * s - acc[q] * inv_one_m)
                g_alpha = dr.select(use & (raw < ALPHA_MAX), g_alpha, 0.0)  # clamped: no dependence
                e = g_alpha * gauss
                e_dv = e * dv
                pixel = (e, e_dv, e_dv * dv, dr.select(use, gpix[q] * w, 0.0))
                sums = [a + b for a, b in zip(sums, pixel)]
                acc[q] = dr.select(use, dr.fma(w, s, acc[q]), acc[q])
                T[q] = dr.select(use, T_k, T[q])
            s_e, s_edv, s_edv2, s_g = sums
            du_e = du * s_e
            lane = [s_e, du_e, s_edv, du * du_e, du * s_edv, s_edv2, s_g, B.Float(0.0)]
            dr.scatter_reduce(dr.ReduceOp.Add, moments, B.jit.ArrayXf(lane), entry, mode=mode)
            return i, tuple(T), tuple(acc)

        zero = tuple(B.Float(0.0) for _ in range(sub))
        dr.while_loop((end, tuple(self.T_final), zero), lambda i, T, acc: i > start, body,
                      labels=("i", "T", "acc"), label="splat_backward")
        dr.eval(moments)
        per_entry = dr.gather(B.jit.ArrayXf, moments, dr.arange(B.UInt32, m), shape=(RECORD, m))
        _, _, ca, cb, cc, op, _ = self.params
        grads = list(_moments_to_grads([per_entry[k] for k in range(RECORD - 1)], ca, cb, cc, op))
        dr.eval(grads)
        names = ("u", "v", "ca", "cb", "cc", "op", "sig")
        for name, gr in zip(names, grads):
            self.set_grad_in(name, gr)

    def name(self):
        return "splat.Rasterize"


def _moments_to_grads(moments, ca, cb, cc, op):
    """A Gaussian's summed moments ``(E, E_u, E_v, E_uu, E_uv, E_vv, G_s)`` (sums over its
    pixels of ``e, e du, e dv, e du^2, e du dv, e dv^2`` and ``dL/dsignal``, with
    ``e = dL/dalpha * exp(-q/2)`` where alpha is not clamped, 0 elsewhere) -> the gradients of
    (u, v, a, b, c, opacity, signal).

    With ``alpha = opacity exp(-q/2)``, ``q = a du^2 + 2b du dv + c dv^2``, ``du = j - u``:
    ``dalpha/du = alpha (a du + b dv)``, ``dalpha/dv = alpha (b du + c dv)``,
    ``dalpha/da = -alpha du^2 / 2``, ``dalpha/db = -alpha du dv``,
    ``dalpha/dc = -alpha dv^2 / 2``, ``dalpha/dopacity = exp(-q/2)``."""
    E, E_u, E_v, E_uu, E_uv, E_vv, G_s = moments
    return (op * (ca * E_u + cb * E_v), op * (cb * E_u + cc * E_v),
            -0.5 * op * E_uu, -op * E_uv, -0.5 * op * E_vv, E, G_s)


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
                         views=views, n=n, height=height, width=width,
                         conic=tuple(dr.detach(x) for x in (proj.conic_a, proj.conic_b, proj.conic_c)))
    return dr.custom(Rasterize, proj.u, proj.v, proj.conic_a, proj.conic_b, proj.conic_c,
                     proj.opacity, proj.signal, lists, views, height, width, tile_lanes)
