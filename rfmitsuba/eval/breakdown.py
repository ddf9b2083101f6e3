"""Where a model breaks: per-image SSIM binned by the geometry of each test position.

Two distances say most about a test position of a moving device:

* **to the fixed device** [m] (the transmitter of a moving-RX dataset, the array of a
  moving-TX one): far from it the direct path weakens against the reflections, and in a
  large room the paths grow longer than the room's small ones;
* **to the nearest training position** [m]: how far a model must interpolate or
  extrapolate (the nearest-neighbour floor falls with it).

:func:`by_distance` bins the test positions into quantiles of one distance and gives, per
bin, its edges and the mean SSIM of each named series (the model and the floors), so a
report can say where a model falls below a floor. :func:`breakdown` computes both.
"""
from __future__ import annotations

import numpy as np

from ..core.errors import ImageError

#: Number of quantile bins of :func:`by_distance`.
BINS = 4
#: The distances of :func:`breakdown`: its keys -> what each measures to ("distance ..." reads it)
DISTANCES = {"to_fixed_device": "to the fixed device", "to_nearest_training": "to the nearest training position"}


def by_distance(distance: np.ndarray, series: dict, *, bins: int = BINS) -> dict:
    """Mean SSIM per quantile bin of ``distance``.

    Args:
        distance: float [K], one distance per test image [m].
        series: name -> float [K] per-image SSIM (e.g. "model", "nearest_neighbour").
        bins: number of bins (>= 1); each holds about K / bins images (fewer bins when
            distances repeat).

    Returns:
        {"edges": float [n + 1] bin edges [m] (the first is the smallest distance, the last the
        largest; a bin holds the images with edges[i] <= d < edges[i + 1], the last also its upper
        edge), "count": int [n] images per bin, and per series name: float [n] mean SSIM per bin}
        as lists, n <= ``bins``.

    Raises:
        ImageError: a series whose length is not K, non-finite distances, or no images.
    """
    d = np.asarray(distance, np.float64).ravel()
    if d.size == 0:
        raise ImageError("by_distance: no test images")
    if not np.isfinite(d).all():
        raise ImageError("by_distance: non-finite distance")
    if bins < 1:
        raise ImageError(f"by_distance: bins must be >= 1, got {bins}")
    for name, s in series.items():
        if np.asarray(s).shape != d.shape:
            raise ImageError(f"by_distance: series {name!r} has shape {np.asarray(s).shape}, distances {d.shape}")
    edges = np.unique(np.quantile(d, np.linspace(0.0, 1.0, bins + 1)))
    if len(edges) == 1:  # every distance equal: one bin
        edges = np.array([edges[0], edges[0]])
    which = np.clip(np.searchsorted(edges, d, side="right") - 1, 0, len(edges) - 2)
    out = {"edges": edges.tolist(), "count": np.bincount(which, minlength=len(edges) - 1).tolist()}
    for name, s in series.items():
        s = np.asarray(s, np.float64)
        out[name] = [float(s[which == b].mean()) if (which == b).any() else float("nan")
                     for b in range(len(edges) - 1)]
    return out


def breakdown(test_pos: np.ndarray, train_pos: np.ndarray, fixed_pos: np.ndarray | None, series: dict, *,
              bins: int = BINS) -> dict:
    """:func:`by_distance` over the distance to the fixed device and to the nearest training position.

    Args:
        test_pos: float [K, 3] moving-device position of each test image [m].
        train_pos: float [M, 3] training positions of the moving device [m].
        fixed_pos: float [3] the fixed device [m], or None (unknown: that part is left out).
        series: name -> float [K] per-image SSIM.
        bins: quantile bins per distance.

    Returns:
        {"to_fixed_device": by_distance result or None, "to_nearest_training": by_distance result}.
    """
    from scipy.spatial import cKDTree

    tp = np.asarray(test_pos, np.float64).reshape(-1, 3)
    trp = np.asarray(train_pos, np.float64).reshape(-1, 3)
    if len(trp) == 0:
        raise ImageError("breakdown: no training positions")
    nearest, _ = cKDTree(trp).query(tp, k=1)
    fixed = None
    if fixed_pos is not None:
        f = np.asarray(fixed_pos, np.float64).reshape(3)
        fixed = by_distance(np.linalg.norm(tp - f, axis=1), series, bins=bins)
    return {"to_fixed_device": fixed, "to_nearest_training": by_distance(nearest, series, bins=bins)}


def fixed_device(data) -> np.ndarray | None:
    """The fixed device of a dataset [m], float [3]: the transmitter of a moving-RX dataset
    (``data.transmitter``), the array of a moving-TX one (``data.view_pos``); None when unknown
    (a moving-RX dataset that names no transmitter)."""
    if data.task == "tx":
        return np.asarray(data.view_pos, np.float64).reshape(-1, 3)[0]
    return None if data.transmitter is None else np.asarray(data.transmitter, np.float64).reshape(3)
