"""The directional scan: matching pursuit on arrival directions in the training PAS, which finds an
unknown room's planes and scatterers (:func:`scan`)."""
from __future__ import annotations


import numpy as np



def pas_pixels(shape: tuple, u: np.ndarray) -> np.ndarray:
    """Flat pixel index (``row * W + col``) of each arrival direction on a PAS grid.

    Args:
        shape: (H, W) of the grid (:mod:`rfmitsuba.rf.grid`, any 90/d x 360/d).
        u: float [..., 3] unit directions in the array frame; arrivals from below fold onto the
            upper hemisphere, as the horizontal array folds them.
    Returns:
        int64 [...].
    """
    h, w = shape
    res = 90.0 / h
    el = np.degrees(np.arcsin(np.clip(np.abs(u[..., 2]), 0.0, 1.0)))
    az = np.degrees(np.arctan2(u[..., 1], u[..., 0])) % 360.0
    row = np.clip(np.rint((el - (res + 1.0) / 2.0) / res).astype(np.int64), 0, h - 1)   # rfmitsuba.rf.grid
    col = np.rint((az - (res - 1.0) / 2.0) / res).astype(np.int64) % w
    return row * w + col

def pas_lookup(pas: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Value of each view's PAS in the arrival direction ``u``.

    Args:
        pas: float [N, H, W] normalised PAS (grid of :mod:`rfmitsuba.rf.grid`, any 90/d x 360/d).
        u: float [N, C, 3] unit directions in the array frame (C candidates per view); arrivals
            from below fold onto the upper hemisphere, as the horizontal array folds them.
    Returns:
        float64 [N, C].
    """
    n, h, w = pas.shape
    return np.asarray(pas, np.float64).reshape(n, -1)[np.arange(n)[:, None], pas_pixels((h, w), u)]

def _unit(d: np.ndarray) -> np.ndarray:
    return d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-9)

def _fold(u: np.ndarray) -> np.ndarray:
    """Directions folded onto the upper hemisphere (what a horizontal array sees)."""
    return np.concatenate([u[..., :2], np.abs(u[..., 2:])], axis=-1)

class _Residual:
    """The training PAS with the directions already explained masked out (matching pursuit on
    arrival directions): :meth:`score` is the mean remaining PAS in each candidate's direction,
    :meth:`explain` masks a beam width around a chosen source's direction at every view."""

    def __init__(self, pas: np.ndarray, radius_deg: float):
        from ...rf.grid import directions

        self.pas = np.array(pas, np.float64, copy=True)
        n, h, w = self.pas.shape
        self.dirs = directions(resolution_deg=90.0 / h).reshape(-1, 3)
        self.cos_r = np.cos(np.radians(radius_deg))

    def score(self, u: np.ndarray) -> np.ndarray:
        """u: float [N, C, 3] array-frame directions -> float [C]."""
        return pas_lookup(self.pas, u).mean(0)

    def score_pixels(self, pixels: np.ndarray) -> np.ndarray:
        """:meth:`score` of directions already turned into pixels (:func:`pas_pixels`, int [N, C])."""
        n = len(self.pas)
        return self.pas.reshape(n, -1)[np.arange(n)[:, None], pixels].mean(0)

    def explain(self, u: np.ndarray) -> None:
        """u: float [N, 3], one chosen source's direction at every view."""
        n, h, w = self.pas.shape
        near = (_fold(u) @ self.dirs.T) >= self.cos_r                  # [N, H*W]
        self.pas.reshape(n, -1)[near] = 0.0

def _greedy(res: _Residual, dirs: np.ndarray, count: int, *, allowed: np.ndarray | None = None) -> list[int]:
    """Pick ``count`` candidates one by one by their score on the residual, explaining each away.

    dirs: float [N, C, 3] directions of every candidate at every view."""
    chosen: list[int] = []
    ok = np.ones(dirs.shape[1], bool) if allowed is None else allowed.copy()
    pixels = pas_pixels(res.pas.shape[1:], dirs) if count else None   # the directions stay; the residual changes
    for _ in range(count):
        if not ok.any():
            break
        sc = np.where(ok, res.score_pixels(pixels), -np.inf)
        i = int(np.argmax(sc))
        if not np.isfinite(sc[i]) or sc[i] <= 0:
            break
        chosen.append(i)
        ok[i] = False
        res.explain(dirs[:, i])
    return chosen

def scan(pas: np.ndarray, x: np.ndarray, y: np.ndarray, *, images: int, scatterers: int, step: float,
         margin: float, rx_to_world: np.ndarray | None = None, radius_deg: float = 12.0, max_views: int = 128,
         max_points: int = 12000) -> dict:
    """Sources that the training PAS imply, for an unknown room (matching pursuit on arrival
    directions; the direct path is explained first).

    Candidates: the images of every transmitter across axis-aligned planes ``coord_a = d`` (offset
    every ``step`` metres within the positions' bounds padded by ``margin``, planes through the
    positions' own span excluded) and fixed scatterers on a grid (every ``max(step, 0.25)`` metres,
    at most about ``max_points`` points, none within 0.3 m of a position). Scores average over at
    most ``max_views`` training views, evenly spaced. A candidate's score is the mean
    of the residual PAS in the direction it would arrive from at every training view; the best is
    kept and a ``radius_deg`` beam around its directions is masked, ``images`` times for planes,
    then ``scatterers`` times for points.

    Args:
        pas: float [N, H, W] normalised training PAS; x, y: float [N, 3] array centres and
            transmitters [m]; rx_to_world: float [3, 3] array frame -> world, or None.
    Returns:
        {"A": float [S, 3, 3] reflections, "b": float [S, 3] [m], "image_score": [S],
         "points": float [P, 3] [m], "point_score": [P]}.
    """
    R = np.eye(3) if rx_to_world is None else np.asarray(rx_to_world, np.float64)
    if len(pas) > max_views:  # the score is a mean over views: an even subset estimates it
        keep = np.linspace(0, len(pas) - 1, max_views).round().astype(np.int64)
        pas, x, y = pas[keep], x[keep], y[keep]
    res = _Residual(pas, radius_deg)
    res.explain(_unit(y - x) @ R)                                    # the direct path
    pts = np.concatenate([x, y])
    lo, hi = pts.min(0) - margin, pts.max(0) + margin
    axis = np.concatenate([np.full(len(np.arange(lo[a], hi[a] + 1e-9, step)), a) for a in range(3)])
    off = np.concatenate([np.arange(lo[a], hi[a] + 1e-9, step) for a in range(3)])
    inside = (off > pts.min(0)[axis] - 0.2) & (off < pts.max(0)[axis] + 0.2)
    img = np.repeat(y[:, None, :], len(off), 1)
    img[:, np.arange(len(off)), axis] = 2 * off[None, :] - y[:, axis]
    img_dirs = _unit(img - x[:, None, :]) @ R
    sc0 = res.score(img_dirs)
    pick = _greedy(res, img_dirs, images, allowed=~inside)
    A = np.repeat(np.eye(3)[None], len(pick), 0)
    b = np.zeros((len(pick), 3))
    for n, i in enumerate(pick):
        A[n, axis[i], axis[i]] = -1.0
        b[n, axis[i]] = 2 * off[i]
    out = {"A": A, "b": b, "image_score": sc0[pick]}
    g = max(step, 0.25, float(np.prod(hi - lo) / max_points) ** (1 / 3))
    grid = np.stack(np.meshgrid(*[np.arange(lo[a] + g / 2, hi[a], g) for a in range(3)], indexing="ij"), -1)
    grid = grid.reshape(-1, 3)
    sub = pts[::max(1, len(pts) // 256)]
    far = np.min(np.linalg.norm(grid[:, None, :] - sub[None], axis=-1), axis=1) >= 0.3
    grid = grid[far]
    if scatterers and len(grid):
        # for a fixed array, points along one ray look alike: keep one candidate per direction cell
        dirs = _unit(grid[None] - x[:, None, :]) @ R                 # [N, G, 3]
        pick = _greedy(res, dirs, scatterers)
        out["points"], out["point_score"] = grid[pick], np.zeros(len(pick))
    else:
        out["points"], out["point_score"] = np.zeros((0, 3)), np.zeros(0)
    return out
