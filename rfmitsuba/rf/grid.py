"""The PAS grid: the one definition of the image every module reads and writes.

Layout: image ``[HEIGHT, WIDTH] = [90, 360]`` at 1 degree. Row ``i`` is elevation
``(i + 1) * res`` degrees above the array plane, column ``j`` azimuth ``j * res`` degrees
from the array's +x axis towards +y (array frame). A grid at ``d`` degrees has
``90/d x 360/d`` pixels sampled at the same rule.
"""
from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError

#: PAS rows: elevation 1..90 degrees
HEIGHT = 90
#: PAS columns: azimuth 0..359 degrees
WIDTH = 360
#: shape of one PAS image, [elevation, azimuth]
PAS_SHAPE = (HEIGHT, WIDTH)


def angle_grid(*, resolution_deg: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Elevation and azimuth of every pixel, radians: two float64 [H, W] arrays (H = 90/res, W = 360/res)."""
    res = float(resolution_deg)
    if not (res > 0) or abs(90.0 / res - round(90.0 / res)) > 1e-9:
        raise ConfigError(f"resolution_deg must divide 90, got {resolution_deg!r}")
    h, w = int(round(90.0 / res)), int(round(360.0 / res))
    el = np.deg2rad((np.arange(h) + 1) * res)
    az = np.deg2rad(np.arange(w) * res)
    return np.meshgrid(el, az, indexing="ij")


def directions(*, resolution_deg: float = 1.0) -> np.ndarray:
    """Unit look directions of every pixel: float64 [H, W, 3], array frame."""
    el, az = angle_grid(resolution_deg=resolution_deg)
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)
