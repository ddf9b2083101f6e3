"""Geometry of the data and of a room for the coherent Gaussian field: how widely the moving device's
positions spread, the defaults that follow from it, a known room box as reflections, and reflections
composed into image sources."""
from __future__ import annotations


import numpy as np

from ...core.errors import ConfigError
from ...rf import array as antenna
from .config import CoherentGaussianConfig


#: planes the data scan finds for an unknown room by default where the moving device's positions
#: lie within the array's beam (CoherentGaussianConfig.images = "auto"; elsewhere none: the pursuit)
SCAN_PLANES = 12

#: the visibility grid every field gets by default (cells along x, y, z), CoherentGaussianConfig.vis_grid
DEFAULT_VIS_GRID = (4, 4, 2)

#: an unknown room's default grid where it has at least DENSE_POSITIONS training positions
DENSE_VIS_GRID = (8, 8, 4)

DENSE_POSITIONS = 1000

def position_spread_deg(fixed: np.ndarray, moving: np.ndarray) -> float:
    """How widely the moving device's positions spread as seen from the fixed device: the median
    angle [degrees] between the directions from ``fixed`` (float [3] or [N, 3] m) to each of
    ``moving`` (float [N, 3] m) and their mean direction."""
    v = np.asarray(moving, np.float64).reshape(-1, 3) - np.asarray(fixed, np.float64).reshape(-1, 3)
    n = np.linalg.norm(v, axis=1)
    v = v[n > 1e-9] / n[n > 1e-9, None]
    if not len(v):
        return 0.0
    m = v.mean(0)
    if np.linalg.norm(m) < 1e-9:                 # positions all round the fixed device
        return 90.0
    return float(np.median(np.degrees(np.arccos(np.clip(v @ (m / np.linalg.norm(m)), -1.0, 1.0)))))

def spreads_wide(data) -> bool:
    """Whether ``data``'s training positions (a :class:`~rfmitsuba.data.views.TrainData`) spread
    wider, seen from the fixed device, than half the array's half-power beamwidth
    (:func:`rfmitsuba.rf.array.half_power_beamwidth_deg`, 13 degrees): a moving device that walks the
    room around the fixed one (our rooms: 21-23 degrees), not tags in a patch far from the gateway
    (NeRF2-like: about 4 degrees). Within the beam a source arrives from about one direction at every
    view, which the data scan's directional search needs; beyond it the plane pursuit finds the
    planes (:class:`CoherentGaussianConfig`, ``pursuit`` and ``images``)."""
    idx = np.asarray(data.train, np.int64)
    x, y, q = data.positions(idx)
    fixed = y if data.task == "rx" else x
    return position_spread_deg(fixed, q) > antenna.half_power_beamwidth_deg() / 2

def scan_planes(cfg: CoherentGaussianConfig, data) -> int:
    """Planes the data scan finds for an unknown room: ``cfg.images``, or where it is "auto"
    :data:`SCAN_PLANES` for positions within the array's beam and none where they spread wider
    (:func:`spreads_wide`: the plane pursuit finds them)."""
    if cfg.images != "auto":
        return int(cfg.images)
    return 0 if spreads_wide(data) else SCAN_PLANES

def uses_pursuit(cfg: CoherentGaussianConfig, data) -> bool:
    """Whether an unknown room's field grows planes by the plane pursuit during training:
    ``cfg.pursuit`` "on" / "off", or "auto": where the positions spread wider than the array's
    beam (:func:`spreads_wide`)."""
    if cfg.pursuit != "auto":
        return cfg.pursuit == "on"
    return spreads_wide(data)

def default_vis_grid(*, init: str, num_positions: int) -> tuple[int, int, int]:
    """The visibility grid of ``vis_grid = "auto"``: :data:`DENSE_VIS_GRID` for an unknown room
    (``init`` "data") with at least :data:`DENSE_POSITIONS` distinct training positions, else
    :data:`DEFAULT_VIS_GRID`. A finer grid draws finer shadows where the data are dense enough to
    show them: NeRF2-like, 2000 tags (1600 training), seeds 0 / 1: 0.920 / 0.918 with (4, 4, 2),
    0.925 / 0.926 (medians 0.942 / 0.944) with (8, 8, 4), 0.927 / 0.946 with (12, 12, 6) on seed
    0 (IDW-3 0.919 / 0.938). With 160 training tags (8, 8, 4) scores 0.956 / 0.960 against
    0.958 +- 0.001; the rooms' 720 positions keep the grid their figures were measured with."""
    if init == "data" and num_positions >= DENSE_POSITIONS:
        return DENSE_VIS_GRID
    return DEFAULT_VIS_GRID

def outside_room_box(box, positions: np.ndarray) -> np.ndarray:
    """Which ``positions`` (float [N, 3] m) lie outside the box ``(x0, y0, z0, x1, y1, z1)`` [m]
    (its faces count as inside): bool [N]."""
    box = np.asarray(box, np.float64).reshape(6)
    pts = np.asarray(positions, np.float64).reshape(-1, 3)
    return ~((pts >= box[:3]) & (pts <= box[3:])).all(axis=1)

def room_box_planes(box, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The six walls of a known room box as reflections ``y -> A y + b``.

    Args:
        box: (x0, y0, z0, x1, y1, z1) [m]; positions: float [N, 3] every known position [m]
            (the moving device's, the array's, the transmitter's), which must lie inside it.
    Returns:
        (A float64 [6, 3, 3], b float64 [6, 3] [m]): x0, x1, y0, y1, z0, z1.
    Raises:
        ConfigError: a position outside the box (named, with its coordinates).
    """
    box = np.asarray(box, np.float64).reshape(6)
    pts = np.asarray(positions, np.float64).reshape(-1, 3)
    outside = outside_room_box(box, pts)
    if outside.any():
        i = int(np.argmax(outside))
        raise ConfigError(f"coherent_gaussians.room_box {box.tolist()}: position {i} at "
                          f"{np.round(pts[i], 3).tolist()} m lies outside the room "
                          f"({int(outside.sum())} of {len(pts)} positions do)")
    A = np.repeat(np.eye(3)[None], 6, 0)
    b = np.zeros((6, 3))
    for k, (axis, offset) in enumerate([(0, box[0]), (0, box[3]), (1, box[1]), (1, box[4]), (2, box[2]), (2, box[5])]):
        A[k, axis, axis] = -1.0
        b[k, axis] = 2.0 * offset
    return A, b

def compose_images(A: np.ndarray, b: np.ndarray, *, max_order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The direct path plus the images of up to ``max_order`` reflections across the given planes.

    Args:
        A, b: float [n, 3, 3] / [n, 3], single reflections ``y -> A y + b``.
        max_order: reflections per image (>= 1); consecutive reflections across one plane cancel
            and are left out, identical maps appear once.
    Returns:
        (A float64 [S, 3, 3], b float64 [S, 3] [m], order int64 [S]), the direct path first.
    """
    out = [(np.eye(3), np.zeros(3), 0, -1)]
    seen = {tuple(np.round(np.concatenate([np.eye(3).ravel(), np.zeros(3)]), 6))}
    frontier = [out[0]]
    for order in range(1, max_order + 1):
        nxt = []
        for Am, bm, _, last in frontier:
            for i in range(len(A)):
                if i == last:
                    continue
                An, bn = A[i] @ Am, A[i] @ bm + b[i]
                key = tuple(np.round(np.concatenate([An.ravel(), bn]), 6))
                if key in seen:
                    continue
                seen.add(key)
                nxt.append((An, bn, order, i))
        out += nxt
        frontier = nxt
    return (np.stack([o[0] for o in out]), np.stack([o[1] for o in out]), np.array([o[2] for o in out], np.int64))

def _check_orthogonal(A: np.ndarray, owner: str) -> None:
    """ConfigError naming ``owner`` unless every map of ``A`` (float [S, 3, 3]) is orthogonal."""
    if not np.allclose(np.einsum("sij,skj->sik", A, A), np.eye(3), atol=1e-6):
        raise ConfigError(f"{owner}: image maps must be orthogonal")
