"""Points shared by the image-source fields (:mod:`~rfmitsuba.models.coherent`,
:mod:`~rfmitsuba.models.coherent_gaussians`, :mod:`~rfmitsuba.models.coherent_person`): host
arrays as device columns, and points as a PLY a splat viewer opens."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .splat import columns, write_ply_arrays


def columns32(a: np.ndarray) -> list:
    """float [K, C] -> list of C ``Float`` [K], gathered from one device buffer
    (:func:`rfmitsuba.models.splat.columns`: kernels stay independent of the host arrays' values and
    alignment, so they compile once)."""
    return columns(np.asarray(a, np.float32).reshape(len(a), -1))


def write_points_ply(path: str | Path, points: np.ndarray, magnitude: np.ndarray) -> Path:
    """Points (float [N, 3] [m]) as small isotropic Gaussians (5 cm) in the 3DGS PLY layout, with
    opacity and signal the magnitude (float [N]) relative to the largest, so a splat viewer shows them."""
    rel = np.clip(magnitude / max(float(np.max(magnitude)), 1e-30), 1e-6, 1 - 1e-6)
    n = len(points)
    return write_ply_arrays(path, points, np.full((n, 3), np.log(0.05)), np.tile([1.0, 0, 0, 0], (n, 1)),
                            np.log(rel / (1 - rel)), signal=rel)
