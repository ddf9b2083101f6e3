"""A folder's profile: the figures that tell a measured folder and a simulated one apart.

A simulator predicts measurements when the folders it makes score like the measured one on
the figures a model meets first (:func:`profile`):

- **floors** on two splits (the folder's own and the spatial block): nearest neighbour, IDW-3
  and the mean image, mean and median SSIM;
- **co-array fit**: how well the 49-coefficient series of a 4 x 4 Bartlett image re-renders the
  spectra (:class:`rfmitsuba.rf.coarray.CoarrayFit`), on the folder's own elevation grid;
- **line of sight**: the mean correlation of the spectra with the pattern of one plane wave from
  the stated transmitter, in the stated array frame and in the best frame found
  (:func:`rfmitsuba.rf.frame_fit.los_frame_fit`);
- **SSIM against distance**: the mean SSIM of the two spectra of a pair of positions, in bins of
  their distance (how fast the spectra change with position).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.ssim import ssim_images
from ..data.split import block_split
from ..data.views import TrainData
from ..rf import array as antenna
from ..rf.coarray import NERF2_ELEVATION_START_DEG, CoarrayFit
from ..rf.frame_fit import los_frame_fit
from .metrics import floors

#: distance bins of the SSIM-against-distance curve [m]
DISTANCE_BINS_M = (0.0, 0.01, 0.02, 0.04, 0.06, 0.10, 0.20, 0.50)
#: the elevation of row 0 of this project's PAS grid [degrees] (rfmitsuba.rf.grid)
PROJECT_ELEVATION_START_DEG = 1.0


def _floor_stats(data: TrainData, train: np.ndarray, test: np.ndarray) -> dict:
    f = floors(data.pas(train), data.antenna_pos[train], data.pas(test), data.antenna_pos[test])
    return {k: {"mean": float(np.mean(f[k])), "median": float(np.median(f[k]))}
            for k in ("nearest_neighbour", "idw3", "mean_image")}


def ssim_by_distance(data: TrainData, *, pairs_per_bin: int = 150, seed: int = 0) -> dict:
    """Mean SSIM of pairs of spectra per distance bin (:data:`DISTANCE_BINS_M`), at most
    ``pairs_per_bin`` pairs per bin drawn at random: {"edges_m", "pairs", "ssim"}."""
    x = data.antenna_pos
    n = len(x)
    i, j = np.triu_indices(n, 1)
    d = np.linalg.norm(x[i] - x[j], axis=1)
    rng = np.random.default_rng(seed)
    edges = np.asarray(DISTANCE_BINS_M)
    out_pairs, out_ssim = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = np.flatnonzero((d >= lo) & (d < hi))
        if len(sel) > pairs_per_bin:
            sel = rng.choice(sel, pairs_per_bin, replace=False)
        out_pairs.append(int(len(sel)))
        out_ssim.append(float(np.mean(ssim_images(data.pas(i[sel]), data.pas(j[sel])))) if len(sel) else None)
    return {"edges_m": edges.tolist(), "pairs": out_pairs, "ssim": out_ssim}


def profile(folder: str | Path, *, pitch_m: float | None = None, coarray_images: int = 20, pairs_per_bin: int = 150,
            frame_candidates: int = 400, frame_views: int = 48, seed: int = 0) -> dict:
    """The profile of a folder of spectra (module docstring).

    Args:
        folder: a NeRF2 folder or an rfmitsuba dataset (one state, its empty room).
        pitch_m: the array's element pitch [m]; None: half a wavelength at the carrier.
        coarray_images: spectra (evenly spaced) the co-array fit scores.
        pairs_per_bin: pairs of spectra per distance bin (:func:`ssim_by_distance`).
        frame_candidates: random frames the line-of-sight fit tries before refining.
        frame_views: spectra (evenly spaced) the line-of-sight fit scores.
        seed: the pairs drawn per distance bin.

    Returns:
        {"folder", "measured", "positions", "floors": {"dataset", "block"}, "coarray_fit",
        "line_of_sight": {"stated", "best", "angle_deg"}, "ssim_by_distance"}.
    """
    data = TrainData.open(folder)
    every = np.union1d(data.train, data.test)
    tr_b, te_b = block_split(data.antenna_pos[every])
    out = {"folder": str(Path(folder)), "measured": bool(getattr(data, "measured", False)), "positions": int(len(every)),
           "floors": {"dataset": _floor_stats(data, np.asarray(data.train), np.asarray(data.test)),
                      "block": _floor_stats(data, every[tr_b], every[te_b])}}
    start = NERF2_ELEVATION_START_DEG if out["measured"] else PROJECT_ELEVATION_START_DEG
    fit = CoarrayFit(frequency_hz=data.frequency_hz, pitch_m=pitch_m or antenna.wavelength(data.frequency_hz) / 2,
                     elevation_start_deg=start)
    pick = every[np.linspace(0, len(every) - 1, min(coarray_images, len(every))).astype(int)]
    pas = data.pas(pick)
    rer = np.stack([fit.fit(p)["image"] for p in pas])
    out["coarray_fit"] = float(np.mean(ssim_images(rer.astype(np.float32), pas)))
    x, y, _ = data.positions(every)
    ff = los_frame_fit(data.pas(every), x, y, rx_to_world=data.rx_to_world, frequency_hz=data.frequency_hz,
                       candidates=frame_candidates, max_views=frame_views)
    out["line_of_sight"] = {"stated": ff.stated_score, "best": ff.score, "angle_deg": ff.angle_deg}
    out["ssim_by_distance"] = ssim_by_distance(data, pairs_per_bin=pairs_per_bin, seed=seed)
    return out

