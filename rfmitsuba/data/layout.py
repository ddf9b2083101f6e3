"""Training positions laid out as a person placing antennas in a room would: a coarse grid over
the free floor.

:func:`grid_layout` picks ``n`` of a dataset's candidate positions (its training split): the
floor under them is cut into square cells, the largest cell size that still leaves at least
``n`` cells holding a candidate is taken, each such cell keeps the candidate nearest its centre,
and where that leaves more than ``n`` the cells' candidates are thinned by farthest-point
selection. The cells that hold candidates are the room's free area (antenna positions are only
drawn in free space); the layout depends on the positions alone (no seed), so every seed and
every method sees the same one, and it knows nothing of the test positions.
"""
from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError

#: cell sizes tried, from the candidates' horizontal extent down, each this factor below the last
_SHRINK = 0.97


def _cell_representatives(xy: np.ndarray, lo: np.ndarray, size: float) -> np.ndarray:
    """Per occupied square cell of side ``size`` [m] (origin ``lo``), the index of the candidate
    nearest the cell's centre (ties: the lower index), in raster order of the cells."""
    cell = np.floor((xy - lo) / size).astype(np.int64)
    centre = lo + (cell + 0.5) * size
    dist = np.linalg.norm(xy - centre, axis=1)
    order = np.lexsort((np.arange(len(xy)), dist, cell[:, 0], cell[:, 1]))
    keys = cell[order]
    first = np.ones(len(order), bool)
    first[1:] = (keys[1:] != keys[:-1]).any(axis=1)
    return order[first]


def _farthest_points(xy: np.ndarray, n: int) -> np.ndarray:
    """``n`` indices of ``xy`` (float [M, 2]) by farthest-point selection, starting from the point
    nearest the centroid (deterministic)."""
    chosen = [int(np.argmin(np.linalg.norm(xy - xy.mean(axis=0), axis=1)))]
    d = np.linalg.norm(xy - xy[chosen[0]], axis=1)
    while len(chosen) < n:
        k = int(np.argmax(d))
        chosen.append(k)
        d = np.minimum(d, np.linalg.norm(xy - xy[k], axis=1))
    return np.asarray(chosen, np.int64)


def grid_layout(positions: np.ndarray, n: int) -> np.ndarray:
    """``n`` of ``positions`` on a coarse horizontal grid over the area they cover.

    Args:
        positions: float [A, 3] candidate antenna positions [m] (x, y horizontal).
        n: how many to keep, >= 1.

    Returns:
        int64 [min(n, A)] indices into ``positions``, ascending; all of them when ``n >= A``.
    """
    pos = np.asarray(positions, np.float64).reshape(-1, 3)
    if n < 1:
        raise ConfigError(f"grid_layout: n must be >= 1, got {n}")
    if n >= len(pos):
        return np.arange(len(pos), dtype=np.int64)
    xy = pos[:, :2]
    lo = xy.min(axis=0)
    size = max(float(np.ptp(xy, axis=0).max()), 1e-6) * (1 + 1e-9)
    reps = _cell_representatives(xy, lo, size)
    while len(reps) < n:
        size *= _SHRINK
        reps = _cell_representatives(xy, lo, size)
    if len(reps) > n:
        reps = reps[_farthest_points(xy[reps], n)]
    return np.sort(reps).astype(np.int64)
