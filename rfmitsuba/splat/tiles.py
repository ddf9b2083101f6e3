"""Tile lists: which projected Gaussians touch which image tile, front to back.

Built on the host with NumPy from the projected centres and extents (one
synchronisation per render call). The image is cut into tiles of
``TILE_H x TILE_W`` pixels (2 x 8 = 16 pixels, one AVX-512 packet of the LLVM
backend, so all lanes of a packet walk the same list). A Gaussian touches the
pixels where ``opacity * exp(-q/2) >= ALPHA_MIN``, i.e. inside the ellipse
``q <= 2 ln(opacity / ALPHA_MIN)``; its axis-aligned bounding box decides its
tiles, so no contribution the rasteriser would keep is lost. Azimuth wraps:
a box crossing column 0 / W touches tiles at both ends of the row.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Tile height and width, pixels.
TILE_H, TILE_W = 2, 8
#: Pixels per tile (= lanes per tile in the rasteriser).
TILE_SIZE = TILE_H * TILE_W
#: Contributions with alpha below this are skipped (as in 3DGS).
ALPHA_MIN = 1.0 / 255.0
#: Alpha is clamped to at most this value.
ALPHA_MAX = 0.99


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


def build(u, v, cov_uu, cov_vv, opacity, depth, *, views: int, height: int, width: int) -> TileLists:
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
