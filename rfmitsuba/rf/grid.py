"""The PAS grid: the one definition of the image every module reads and writes.

Layout: image ``[HEIGHT, WIDTH] = [90, 360]`` at 1 degree. Row ``i`` is elevation
``(i + 1) * res`` degrees above the array plane, column ``j`` azimuth ``j * res`` degrees
from the array's +x axis towards +y (array frame).

A coarser grid at ``d`` degrees (``90/d x 360/d`` pixels) holds the ``d x d`` block means of the
1-degree image (:func:`rfmitsuba.data.views.downsample`: what training at ``downsample = d``
fits), so its pixel ``(i, j)`` is sampled at the centre of its block: elevation
``i * d + (d + 1) / 2``, azimuth ``j * d + (d - 1) / 2`` degrees. At ``d = 1`` that is the rule
above. (Sampling a coarse grid at ``(i + 1) * d``, ``j * d`` instead put every pixel half a
degree of elevation and of azimuth away from the block it is compared with at ``d = 2``.)
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


def angle_grid(*, resolution_deg: float = 1.0, elevation_start_deg: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Elevation and azimuth of every pixel, radians: two float64 [H, W] arrays (H = 90/res,
    W = 360/res), at the centres of the pixels' blocks of the 1-degree grid (module docstring).

    ``elevation_start_deg``: the elevation of the 1-degree grid's row 0 [degrees]; 1 is this
    project's grid, 0 the published NeRF2 folders' (:data:`rfmitsuba.rf.coarray.NERF2_ELEVATION_START_DEG`)."""
    res = float(resolution_deg)
    if not (res >= 1.0) or abs(90.0 / res - round(90.0 / res)) > 1e-9:
        raise ConfigError(f"resolution_deg must be >= 1 and divide 90, got {resolution_deg!r}")
    h, w = int(round(90.0 / res)), int(round(360.0 / res))
    el = np.deg2rad((elevation_start_deg - 1.0) + np.arange(h) * res + (res + 1.0) / 2.0)
    az = np.deg2rad(np.arange(w) * res + (res - 1.0) / 2.0)
    return np.meshgrid(el, az, indexing="ij")


def directions(*, resolution_deg: float = 1.0, elevation_start_deg: float = 1.0) -> np.ndarray:
    """Unit look directions of every pixel: float64 [H, W, 3], array frame (options as :func:`angle_grid`)."""
    el, az = angle_grid(resolution_deg=resolution_deg, elevation_start_deg=elevation_start_deg)
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)
