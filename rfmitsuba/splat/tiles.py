"""Tile lists: which projected Gaussians touch which image tile, front to back.

Built on the device with Dr.Jit (:func:`build`): bounding boxes of tiles per
(view, Gaussian), a depth sort (``dr.argsort``), an exact integer prefix sum
for the pair offsets, a max-scan to find each pair's Gaussian, and a stable
counting sort by tile (``dr.detail.block_mkperm``). The only host
synchronisation is reading the number of pairs. :func:`build_numpy` is the
same construction in NumPy (kept as an independent check for the tests). The image is cut into tiles of
``TILE_H x TILE_W`` pixels (8 x 8 = 64 pixels, drawn by 8 lanes of eight
pixels on the LLVM backend -- :func:`lanes_per_tile` -- so the lanes of a tile
walk the same list in one packet, and a backward step's sums over a lane's
eight pixels are one addition; on AVX-512, 2x8, 4x8 and 16x8 tiles measured
slower). A Gaussian touches the
pixels where ``opacity * exp(-q/2) >= ALPHA_MIN``, i.e. inside the ellipse
``q <= 2 ln(opacity / ALPHA_MIN)``; its axis-aligned bounding box decides its
tiles, so no contribution the rasteriser would keep is lost. Given the conic,
:func:`build` also drops the tiles of the box that the ellipse misses (the
least ``q`` over a tile's pixel rectangle, exact; 11.7% of the pairs of
``rfmitsuba bench splat``'s scene), which changes no bit of the image and
its gradients only by float32 rounding (another summation order). Azimuth
wraps: a box crossing column 0 / W touches tiles at both ends of the row.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import drjit as dr
import numpy as np

from ..core import backend as B
from ..core.errors import ConfigError

#: Tile height and width, pixels.
TILE_H, TILE_W = 8, 8
#: Pixels per tile.
TILE_SIZE = TILE_H * TILE_W
#: Lane counts the rasteriser accepts per tile (multiples of TILE_W dividing TILE_SIZE).
TILE_LANE_CHOICES = (8, 16, 32, 64)
#: Contributions with alpha below this are skipped (as in 3DGS).
ALPHA_MIN = 1.0 / 255.0
#: Alpha is clamped to at most this value.
ALPHA_MAX = 0.99


def lanes_per_tile() -> int:
    """Lanes of the rasteriser per tile.

    Each lane draws ``TILE_SIZE / lanes`` pixels of one column, ``lanes / TILE_W`` rows apart.
    LLVM: 8 lanes of eight pixels, so an AVX-512 packet (16 lanes) walks two tiles' lists at
    once, an AVX2 packet one, a NEON packet half of one. CUDA: 16 (a warp draws two tiles).
    Measured on AVX-512 (after the pair records and the moments of
    :mod:`rfmitsuba.splat.raster`; 16 lanes had been the AVX-512 choice since the backward pass
    reduced each pair's gradients across the packet): a training iteration at 10 000 Gaussians
    7.1-7.3 ms against 8.1-8.3 ms for 16 lanes (alternating processes), at 50 000 29.6-32.2
    against 33.8-37.1 ms, at 2000 3.8 against 3.9-4.1 ms; the op alone on 2 threads, forward 1.74
    against 1.85 ms, backward 3.1 against 3.8 ms (a step's record load and moment addition
    shared by eight pixels instead of four); the Stage-1 splat step 66-67 against 68-71 ms at 90 x 360,
    45-50 against 45-46 ms at 45 x 180. On an AVX2 host (earlier code, ``rfmitsuba bench splat``):
    under load 3.5-4.5, 8 lanes took 58-63 ms per iteration against 72-80 ms for 16. The
    environment variable ``RFMITSUBA_SPLAT_LANES`` (one of :data:`TILE_LANE_CHOICES`) overrides
    the choice.

    Raises:
        ConfigError: ``RFMITSUBA_SPLAT_LANES`` is not one of :data:`TILE_LANE_CHOICES`.
    """
    env = os.environ.get("RFMITSUBA_SPLAT_LANES", "").strip()
    if env:
        # ASCII digits only: str.isdigit() is true for "²", which int() refuses
        return checked_lanes(int(env) if env.isascii() and env.isdigit() else env, what="RFMITSUBA_SPLAT_LANES")
    return 16 if B.is_cuda() else 8


def checked_lanes(lanes, *, what: str) -> int:
    """``lanes`` if it is one of :data:`TILE_LANE_CHOICES`, else ConfigError naming ``what``."""
    if isinstance(lanes, bool) or lanes not in TILE_LANE_CHOICES:
        raise ConfigError(f"{what} must be one of {TILE_LANE_CHOICES}, got {lanes!r}")
    return int(lanes)


def wrap_offset(du, width):
    """An azimuth offset ``du`` (pixels, Float) taken to the nearest copy of the centre,
    ``[-width/2, width/2)`` for ``|du| < 3 width / 2``: the rasteriser's wrap at 0/360 deg."""
    du = dr.select(du >= 0.5 * width, du - width, du)
    return dr.select(du < -0.5 * width, du + width, du)


def tile_grid(height: int, width: int) -> tuple[int, int]:
    """Number of tile rows and tile columns covering a height x width image."""
    return -(-height // TILE_H), -(-width // TILE_W)


@dataclass
class TileLists:
    """Flattened per-tile lists.

    entries: uint32 [P], (view, Gaussian) index b*N + i of each pair, grouped
    by tile (view-major, then tile row, then tile column) and sorted by depth
    within a tile; offsets: uint32 [num_tiles + 1], tile t owns
    ``entries[offsets[t]:offsets[t+1]]``.
    """

    entries: np.ndarray
    offsets: np.ndarray


def build_numpy(u, v, cov_uu, cov_vv, opacity, depth, *, views: int, height: int, width: int) -> TileLists:
    """Build the tile lists of ``views`` views.

    Args:
        u, v: float32 [B*N], projected centre, pixels (view-major, b*N + i).
        cov_uu, cov_vv: float32 [B*N], covariance diagonal, pixels^2.
        opacity: float32 [B*N], 0 for culled entries.
        depth: float32 [B*N], distance to the receiver, metres (sort key).
        views: B; height, width: image size, pixels.

    Entries with any non-finite value, opacity below ALPHA_MIN, or no pixel
    inside the image are dropped.
    """
    m = u.shape[0]
    n = m // views if views else 0
    nty, ntx = tile_grid(height, width)
    tiles_per_view = nty * ntx
    num_tiles = views * tiles_per_view
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        ok = (np.isfinite(u) & np.isfinite(v) & np.isfinite(cov_uu) & np.isfinite(cov_vv)
              & np.isfinite(depth) & np.isfinite(opacity) & (opacity >= ALPHA_MIN)
              & (cov_uu > 0) & (cov_vv > 0))
        k2 = 2.0 * np.log(np.where(ok, opacity, 1.0).astype(np.float64) / ALPHA_MIN)
        ext_u = np.sqrt(k2 * np.where(ok, cov_uu, 0.0))
        ext_v = np.sqrt(k2 * np.where(ok, cov_vv, 0.0))
        uu = np.where(ok, u, 0.0).astype(np.float64)
        vv = np.where(ok, v, 0.0).astype(np.float64)
        r0 = np.maximum(np.ceil(vv - ext_v), 0.0)
        r1 = np.minimum(np.floor(vv + ext_v), height - 1.0)
        c0 = np.ceil(uu - ext_u)
        c1 = np.floor(uu + ext_u)
    ok &= r0 <= r1
    ok &= c0 <= c1
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return TileLists(np.zeros(0, np.uint32), np.zeros(num_tiles + 1, np.uint32))
    # Front to back within each view: sort by (view, depth).
    view = idx // n
    order = np.lexsort((depth[idx], view))
    idx = idx[order]
    view = view[order]
    r0 = r0[idx].astype(np.int64)
    r1 = r1[idx].astype(np.int64)
    c0 = c0[idx]
    c1 = c1[idx]
    full = (c1 - c0 + 1) >= width
    a = np.where(full, 0, np.mod(np.clip(c0, -width, 2 * width), width)).astype(np.int64)
    b = np.where(full, width - 1, np.mod(np.clip(c1, -width, 2 * width), width)).astype(np.int64)
    wrapped = a > b
    tx0 = a // TILE_W
    tx1 = np.where(wrapped, ntx - 1, b // TILE_W)
    tx2 = np.where(wrapped, b // TILE_W, -1)  # second run of tile columns [0, tx2]
    merge = wrapped & (tx2 >= tx0)  # both runs share a tile column: the whole row
    tx0 = np.where(merge, 0, tx0)
    tx1 = np.where(merge, ntx - 1, tx1)
    tx2 = np.where(merge, -1, tx2)
    ncol1 = tx1 - tx0 + 1
    ncols = ncol1 + tx2 + 1
    ty0 = r0 // TILE_H
    nrows = r1 // TILE_H - ty0 + 1
    count = nrows * ncols
    total = int(count.sum())
    start = np.cumsum(count) - count
    rep = np.repeat(np.arange(idx.size), count)
    k = np.arange(total, dtype=np.int64) - start[rep]
    nc = ncols[rep]
    row = k // nc
    col = k - row * nc
    n1 = ncol1[rep]
    tx = np.where(col < n1, tx0[rep] + col, col - n1)
    tile = view[rep] * tiles_per_view + (ty0[rep] + row) * ntx + tx
    key = tile.astype(np.uint16) if num_tiles <= 65536 else tile.astype(np.uint32)
    perm = np.argsort(key, kind="stable")
    entries = idx[rep[perm]].astype(np.uint32)
    counts = np.bincount(tile, minlength=num_tiles)
    offsets = np.zeros(num_tiles + 1, np.uint32)
    np.cumsum(counts, out=offsets[1:])
    return TileLists(entries, offsets)


@dataclass
class DeviceTileLists:
    """Like :class:`TileLists`, as Dr.Jit UInt32 arrays (``entries`` may be a
    size-1 dummy when there are no pairs; ``count`` says how many there are)."""

    entries: object
    offsets: object
    count: int


#: Relative and absolute widening of the boxes (pixels), so that float32
#: rounding never drops a pixel the rasteriser would keep.
_BOX_REL, _BOX_ABS = 1e-5, 1e-3
#: The same for the per-tile test of :func:`build` (on ``q``, a squared distance).
_CULL_REL, _CULL_ABS = 1e-4, 1e-2


def _rects(u, v, cov_uu, cov_vv, opacity, depth, height, width):
    """Per entry: tile rows [ty0, ty0 + nrows), tile columns [tx0, tx0 + ncol1) and
    [0, ncol2) (the part that wrapped past 360 deg); count = nrows*(ncol1+ncol2); and k2, the
    ellipse's bound ``q <= k2 = 2 ln(opacity / ALPHA_MIN)``."""
    UInt32, Int32 = B.UInt32, B.Int32
    nty, ntx = tile_grid(height, width)
    ok = (dr.isfinite(u) & dr.isfinite(v) & dr.isfinite(cov_uu) & dr.isfinite(cov_vv)
          & dr.isfinite(depth) & (opacity >= ALPHA_MIN) & (cov_uu > 0) & (cov_vv > 0))
    k2 = 2.0 * dr.log(dr.maximum(opacity, ALPHA_MIN) * (1.0 / ALPHA_MIN))
    ext_u = dr.sqrt(k2 * dr.select(ok, cov_uu, 0.0)) * (1.0 + _BOX_REL) + _BOX_ABS
    ext_v = dr.sqrt(k2 * dr.select(ok, cov_vv, 0.0)) * (1.0 + _BOX_REL) + _BOX_ABS
    uu = dr.select(ok, u, 0.0)
    vv = dr.select(ok, v, 0.0)
    r0 = dr.maximum(dr.ceil(vv - ext_v), 0.0)
    r1 = dr.minimum(dr.floor(vv + ext_v), height - 1.0)
    c0 = dr.ceil(uu - ext_u)
    c1 = dr.floor(uu + ext_u)
    ok &= (r0 <= r1) & (c0 <= c1)
    full = ~((c1 - c0 + 1.0) < width)  # also catches infinite extents
    c0 = dr.select(full, 0.0, c0)
    c1 = dr.select(full, width - 1.0, c1)
    a = Int32(dr.select(ok, c0, 0.0))
    b = Int32(dr.select(ok, c1, 0.0))
    a = dr.select(a < 0, a + width, dr.select(a >= width, a - width, a))
    b = dr.select(b < 0, b + width, dr.select(b >= width, b - width, b))
    wrapped = a > b
    tx0 = a // TILE_W
    tx1 = dr.select(wrapped, ntx - 1, b // TILE_W)
    tx2 = dr.select(wrapped, b // TILE_W, -1)
    merge = wrapped & (tx2 >= tx0)
    tx0 = dr.select(merge, 0, tx0)
    tx1 = dr.select(merge, ntx - 1, tx1)
    tx2 = dr.select(merge, -1, tx2)
    ncol1 = tx1 - tx0 + 1
    ncols = ncol1 + tx2 + 1
    ty0 = Int32(dr.select(ok, r0, 0.0)) // TILE_H
    nrows = Int32(dr.select(ok, r1, 0.0)) // TILE_H - ty0 + 1
    count = dr.select(ok, UInt32(nrows * ncols), 0)
    return count, UInt32(ty0), UInt32(tx0), UInt32(ncol1), UInt32(ncols), k2


def _edge_min(a, b, c, x, y0, y1):
    """min over y in [y0, y1] of ``a x^2 + 2b x y + c y^2`` (c > 0)."""
    y = dr.clip(-b * x / c, y0, y1)
    return a * x * x + 2.0 * b * x * y + c * y * y


def _reaches(ca, cb, cc, du0, du1, dv0, dv1, k2):
    """Whether ``q = a du^2 + 2b du dv + c dv^2`` falls to ``k2`` (widened like the boxes)
    somewhere in the rectangle [du0, du1] x [dv0, dv1] (offsets from the centre, pixels): 0
    where it holds the centre, else the least of its four edges (exact for a positive definite
    conic; anything else, or a NaN, counts as reaching)."""
    inside = (du0 <= 0.0) & (du1 >= 0.0) & (dv0 <= 0.0) & (dv1 >= 0.0)
    q = dr.minimum(dr.minimum(_edge_min(ca, cb, cc, du0, dv0, dv1), _edge_min(ca, cb, cc, du1, dv0, dv1)),
                   dr.minimum(_edge_min(cc, cb, ca, dv0, du0, du1), _edge_min(cc, cb, ca, dv1, du0, du1)))
    definite = (ca > 0.0) & (cc > 0.0) & (ca * cc > cb * cb)
    return inside | ~definite | ~(q > k2 * (1.0 + _CULL_REL) + _CULL_ABS)


#: Floats per entry record of :func:`build`'s tile test (centre, bound, conic; one packet load).
RECORD_TILE = 8


def _pair_reaches_tile(uu, vv, k2, conic, tx, ty, height, width):
    """Per pair (its entry's centre ``uu, vv``, bound ``k2`` and conic, Float each; tile column
    ``tx`` and row ``ty``): whether some pixel of the tile may get ``alpha >= ALPHA_MIN`` from
    the entry (:func:`_reaches` on the tile's pixel rectangle against the entry's bound ``k2``,
    azimuth offsets wrapped as the rasteriser wraps them; a rectangle that the wrap would cut
    counts as reached)."""
    Float = B.Float
    ca, cb, cc = conic
    x0 = Float(tx * TILE_W)
    x1 = dr.minimum(x0 + (TILE_W - 1), width - 1.0)
    y0 = Float(ty * TILE_H)
    y1 = dr.minimum(y0 + (TILE_H - 1), height - 1.0)
    du0, du1 = wrap_offset(x0 - uu, width), wrap_offset(x1 - uu, width)
    cut = ~(dr.abs((du1 - du0) - (x1 - x0)) < 0.5)
    return cut | _reaches(ca, cb, cc, du0, du1, y0 - vv, y1 - vv, k2)


def build(u, v, cov_uu, cov_vv, opacity, depth, *, views: int, n: int, height: int,
          width: int, conic=None) -> DeviceTileLists:
    """Tile lists of ``views`` views on the device.

    Args:
        u, v, cov_uu, cov_vv, opacity, depth: Float [B*N] (detached), as in
            :class:`rfmitsuba.splat.project.Projected`.
        views, n: B and N; height, width: image size, pixels.
        conic: optional (a, b, c), Float [B*N] each (detached), the conic of
            :class:`~rfmitsuba.splat.project.Projected`. With it, a pair whose tile the
            Gaussian's ``alpha >= ALPHA_MIN`` ellipse misses (a corner of its bounding box)
            is dropped from its tile's list: it stays in the pair arrays (``count``) after
            the last tile's pairs, where no list reaches it. Without it every tile of the
            box keeps the pair (as :func:`build_numpy`).

    Entries with any non-finite value, opacity below ALPHA_MIN, or no pixel
    inside the image get no pairs.
    """
    UInt32 = B.UInt32
    nty, ntx = tile_grid(height, width)
    tiles_per_view = nty * ntx
    num_tiles = views * tiles_per_view
    count, ty0, tx0, ncol1, ncols, k2 = _rects(u, v, cov_uu, cov_vv, opacity, depth, height, width)
    dr.eval(count, ty0, tx0, ncol1, ncols, k2)  # one kernel (each gather below would re-run it)
    # Front to back: one global depth sort. The tile sort below is stable and tiles
    # belong to one view, so every tile list is in depth order of its own view.
    key = dr.select(count > 0, depth, dr.inf)
    order = dr.argsort(dr.select(dr.isnan(key), dr.inf, key))
    count_s = dr.gather(UInt32, count, order)
    start = dr.prefix_sum(count_s)  # exclusive, exact (integers)
    last = dr.opaque(UInt32, dr.width(count_s) - 1)
    total = int((dr.gather(UInt32, start, last) + dr.gather(UInt32, count_s, last))[0])
    offsets_default = dr.zeros(UInt32, num_tiles + 1)
    if total == 0:
        return DeviceTileLists(UInt32(0), offsets_default, 0)
    # Each pair's sorted-entry position: mark where each non-empty entry starts, max-scan.
    m = dr.width(count_s)
    mark = dr.zeros(UInt32, total)
    pos = dr.arange(UInt32, m)
    dr.scatter(mark, pos, start, count_s > 0)
    s = dr.block_prefix_reduce(dr.ReduceOp.Max, mark, block_size=total, exclusive=False)
    # What a pair reads of its entry, packed per sorted entry (one packet load per pair instead
    # of a gather per value: a vector gather is slow on x86): its first pair, the entry, its
    # first tile (column | row << 16) and its tile columns (first part | all << 16); tile
    # coordinates are below 2^16. With the conic also its centre, bound and conic.
    rec_int = dr.empty(UInt32, 4 * m)
    dr.scatter(rec_int, B.jit.ArrayXu([start, order, dr.gather(UInt32, tx0 | (ty0 << 16), order),
                                       dr.gather(UInt32, ncol1 | (ncols << 16), order)]), pos)
    if conic is not None:
        rec_f = dr.empty(B.Float, RECORD_TILE * m)
        dr.scatter(rec_f, B.jit.ArrayXf([dr.gather(B.Float, x, order) for x in (u, v, k2) + tuple(conic)]
                                        + [B.Float(0.0)] * (RECORD_TILE - 6)), pos)
    p = dr.arange(UInt32, total)
    first, e, txy, cols = dr.gather(B.jit.ArrayXu, rec_int, s, shape=(4, total))
    k = p - first
    nc = dr.maximum(cols >> 16, 1)  # >= 1 also in padding lanes (no SIGFPE)
    n1 = cols & 0xFFFF
    row = k // nc
    col = k - row * nc
    tx = dr.select(col < n1, (txy & 0xFFFF) + col, col - n1)
    view = e // dr.opaque(UInt32, n)
    ty = (txy >> 16) + row
    tile = view * tiles_per_view + ty * ntx + tx
    if conic is not None:  # dead pairs take the key num_tiles: after every tile, in no list
        r = dr.gather(B.jit.ArrayXf, rec_f, s, shape=(RECORD_TILE, total))
        tile = dr.select(_pair_reaches_tile(r[0], r[1], r[2], (r[3], r[4], r[5]), tx, ty, height, width),
                         tile, num_tiles)
    dr.eval(tile, e)
    buckets = 1 << max(int(num_tiles).bit_length(), 1)
    perm = dr.detail.block_mkperm(tile, total, buckets)
    entries = dr.gather(UInt32, e, perm)
    # offsets[t] = first sorted pair with tile >= t (binary search, fixed 32 steps; each step reads
    # the pair's tile through the permutation, instead of a gather of all the tiles into order)
    t = dr.arange(UInt32, num_tiles + 1)
    total_o = dr.opaque(UInt32, total)
    offsets = dr.binary_search(0, (1 << 31) - 1, lambda i: (i < total_o) & (
        dr.gather(UInt32, tile, dr.gather(UInt32, perm, dr.minimum(i, total_o - 1))) < t))
    offsets = dr.minimum(UInt32(offsets), total_o)
    dr.eval(entries, offsets)
    return DeviceTileLists(entries, offsets, total)
