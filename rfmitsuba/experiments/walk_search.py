"""Stage 2 without a tracker: the person's walk from the order of its frames alone.

Ours (two-stage) trains its person field on the person's position at every walk frame, which a
real deployment knows only with a camera or a tracker. Here those positions are unknown: a frame
is known by its place in the walk (its index, and where the dataset states it, the time between
frames). With the background fixed, the walk is estimated and the person field trained on it,
in rounds:

1. **Grid.** For every training frame, the loss of a person field with the feet at every free
   point of a grid over the room [m] (``grid_m``), from the ``views`` of the frame's PAS that the
   person changes most (against the empty room's PAS measured at the same antenna), fitted on top
   of those empty-room PAS (:class:`rfmitsuba.eval.locate.Query`).
2. **Walk.** The path through the grid points, one per frame in walk order, that minimises the
   frames' losses (each frame's losses standardised, so every frame weighs alike), stepping at
   most ``max_speed_mps`` times the time between two frames plus one grid step (dynamic
   programming over the grid: Viterbi). Without a stated frame interval the steps are free.
3. **Descent.** Each frame's point on that path is refined by descent on the position
   (:func:`rfmitsuba.eval.locate.refine`), kept where it is when the descent finds no lower loss.
4. **Training.** The Stage-2 person field trains on the estimated walk exactly as Ours trains on
   the tracked one; the next round searches with that trained field. The model is the round
   whose field draws its validation PAS (training frames at their estimated positions) best:
   where the person changes little, later rounds can drift away from the walk.

The first round searches with an untrained person field that blocks the background's paths near
the body (blockage strength ``search_strength``, no scatterers): what a body does before anything
is learned. The room's free space comes from its scene; a dataset without one is searched over
the box of its moving device's positions grown by 1 m, at the floor of the dataset's bounds.

Nothing here reads the dataset's person positions: they are used afterwards, only to report the
walk's error (:func:`walk_error`).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.atomic import write_json_with_numpy
from ..core.errors import ConfigError, DatasetError
from ..data.samples import SampleData, feature_box
from ..eval.locate import Query, SearchRegion, TwoStage, refine

#: the box of the moving device's positions grown by this much [m] where no room is known
OPEN_MARGIN_M = 1.0


@dataclass
class WalkSearchConfig:
    """How Ours (no tracker) estimates the walk (module docstring; the measurements behind the
    defaults are in the lab notes).

    - rounds: Stage-2 trainings, each on the walk searched with the field before it, >= 1 (4).
    - grid_m: grid spacing of the coarse search [m] (0.25).
    - views: PAS per frame compared, those the person changes most (12).
    - max_speed_mps: fastest walk between two frames [m/s]; 0: no bound (1.5).
    - search_strength: blockage strength of the untrained first search field, in [0, 1) (0.2).
    - descent_steps: descent steps per frame after the walk; 0 keeps the grid point (12).
    """

    rounds: int = 4
    grid_m: float = 0.25
    views: int = 12
    max_speed_mps: float = 1.5
    search_strength: float = 0.2
    descent_steps: int = 12

    def __post_init__(self) -> None:
        if self.rounds < 1 or self.views < 1 or self.descent_steps < 0:
            raise ConfigError("WalkSearchConfig: rounds and views must be >= 1 and descent_steps >= 0")
        if not self.grid_m > 0 or self.max_speed_mps < 0:
            raise ConfigError("WalkSearchConfig: grid_m must be > 0 and max_speed_mps >= 0")
        if not 0 <= self.search_strength < 1:
            raise ConfigError("WalkSearchConfig: search_strength must be in [0, 1)")


def training_frames(data: SampleData) -> np.ndarray:
    """The walk frames the person field trains on, in walk order: int64 [F] walk indices ``h``
    (state ``h + 1``)."""
    states = np.unique(data.states[data.train])
    return np.sort(states[states > 0] - 1).astype(np.int64)


def frame_interval_s(data: SampleData) -> float | None:
    """The time between two consecutive walk frames [s] where the dataset states it (a generated
    dataset: its walk's duration over its frames), else None."""
    meta = getattr(data._ds, "meta", {}) or {}
    gen = meta.get("generate") if isinstance(meta.get("generate"), dict) else {}
    n, duration = gen.get("person_positions"), gen.get("walk_duration_s")
    if not n or not duration or int(n) < 2:
        return None
    return float(duration) / (int(n) - 1)


def search_region(data: SampleData) -> SearchRegion:
    """Where the feet may be: the known room's free space, or (no room) the moving device's box
    grown by :data:`OPEN_MARGIN_M`, at the floor of the dataset's bounds."""
    from ..eval.locate import CLEARANCE_M

    if data.scene_xml is not None:
        from ..sim.geometry import RoomGeometry

        geometry = RoomGeometry.from_xml(data.scene_xml)
        lo, hi = geometry.bounds
        return SearchRegion(lo=np.asarray(lo[:2] + CLEARANCE_M, np.float64), hi=np.asarray(hi[:2] - CLEARANCE_M, np.float64),
                            z=float(lo[2]), geometry=geometry, kind="room")
    ap = np.asarray(data.antenna_pos, np.float64)
    lo, hi = ap[:, :2].min(0) - OPEN_MARGIN_M, ap[:, :2].max(0) + OPEN_MARGIN_M
    return SearchRegion(lo=lo, hi=hi, z=float(np.asarray(data.bounds)[0][2]), kind="open")


def frame_queries(model: TwoStage, frames: np.ndarray, *, views: int) -> list[Query]:
    """One :class:`~rfmitsuba.eval.locate.Query` per walk frame: the ``views`` of the frame's
    training PAS that differ most from the empty room's PAS at the same antenna (lowest SSIM
    between the two measurements: where the person changes the most), against those empty-room
    PAS."""
    from ..core.ssim import ssim_images
    from ..rf.bartlett_ref import normalize

    data = model.data
    train = np.asarray(data.train)
    empty = data._ds.pas(0)
    out = []
    for h in frames:
        rows = train[data.states[train] == h + 1]
        if len(rows) == 0:
            raise DatasetError(f"{data.path}: walk frame {int(h)} has no training PAS")
        pas = data.pas(rows)
        ref = normalize(np.asarray(empty[np.asarray(data.antennas[rows])], np.float32))
        pick = np.sort(np.argsort(ssim_images(normalize(pas), ref), kind="stable")[:views])
        out.append(Query(model, pas[pick], data.antenna_pos[rows[pick]], empty=ref[pick]))
    return out


def best_walk(losses: np.ndarray, grid: np.ndarray, max_step_m: np.ndarray | None) -> np.ndarray:
    """The path through grid points, one per frame, of least summed standardised loss.

    Args:
        losses: float [F, G] each frame's loss at each grid point; grid: float [G, 2] [m];
        max_step_m: float [F - 1] the longest step allowed between frames f and f + 1 [m], or None
            (free steps).

    Returns:
        int64 [F] the grid point of each frame.
    """
    loss = np.asarray(losses, np.float64)
    f, g = loss.shape
    z = (loss - loss.mean(1, keepdims=True)) / np.maximum(loss.std(1, keepdims=True), 1e-12)
    if max_step_m is None:
        return np.argmin(z, axis=1).astype(np.int64)
    d = np.hypot(*(np.asarray(grid)[:, None, :] - np.asarray(grid)[None, :, :]).transpose(2, 0, 1))
    cost = z[0].copy()
    back = np.zeros((f, g), np.int64)
    for t in range(1, f):
        allowed = np.where(d <= max_step_m[t - 1], 0.0, np.inf)        # [from, to]
        total = cost[:, None] + allowed
        back[t] = np.argmin(total, axis=0)
        cost = total[back[t], np.arange(g)] + z[t]
    path = np.empty(f, np.int64)
    path[-1] = int(np.argmin(cost))
    for t in range(f - 1, 0, -1):
        path[t - 1] = back[t, path[t]]
    return path


def search_walk(model: TwoStage, frames: np.ndarray, cfg: WalkSearchConfig, *, interval_s: float | None,
                region: SearchRegion, quiet: bool = True) -> dict:
    """One round's walk: grid, best walk, descent (module docstring); ``quiet``: no progress bars.

    Returns:
        {"positions": float64 [F, 3] feet [m], "grid_positions": float64 [F, 3] the walk's grid
        points, "losses": float64 [F], "grid_points": G, "max_step_m": the step bound or None}.
    """
    from ..core.progress import bar

    queries = frame_queries(model, frames, views=cfg.views)
    grid = region.grid(cfg.grid_m)
    with bar(len(queries), desc="walk search: grid", unit="frame", quiet=quiet) as b:
        losses = []
        for q in queries:
            losses.append(q.losses(grid))
            b.update()
    losses = np.stack(losses)
    step = None
    if interval_s is not None and cfg.max_speed_mps > 0:
        step = cfg.max_speed_mps * interval_s * np.diff(frames).astype(np.float64) + cfg.grid_m
    path = best_walk(losses, grid, step)
    xy = grid[path].copy()
    best = losses[np.arange(len(frames)), path].copy()
    if cfg.descent_steps:
        kind = "ad" if model.differentiable else "nelder_mead"
        with bar(len(queries), desc="walk search: descent", unit="frame", quiet=quiet) as b:
            for i, q in enumerate(queries):
                x, loss = refine(q, region, xy[i:i + 1], steps=cfg.descent_steps, grid_m=cfg.grid_m, descent=kind)
                if loss[0] < best[i]:
                    xy[i], best[i] = x[0], loss[0]
                b.update()
    return {"positions": region.feet(xy), "grid_positions": region.feet(grid[path]), "losses": best,
            "grid_points": len(grid), "max_step_m": None if step is None else float(step.max())}


def walk_error(data: SampleData, frames: np.ndarray, positions: np.ndarray) -> dict:
    """Horizontal error of an estimated walk against the dataset's person positions [cm]:
    {"median_cm", "p90_cm", "mean_cm", "frames"}; on a walk of several people also against the
    nearest person at each frame ("nearest_person_median_cm", "nearest_person_p90_cm")."""
    frames = np.asarray(frames)
    truth = np.asarray(data._ds.person_pos, np.float64)[frames + 1]
    p = np.asarray(positions, np.float64)
    err = 100.0 * np.hypot(*(p[:, :2] - truth[:, :2]).T)
    out = {"median_cm": float(np.median(err)), "p90_cm": float(np.percentile(err, 90)),
           "mean_cm": float(err.mean()), "frames": int(len(err))}
    people = np.asarray(getattr(data._ds, "people_pos", truth[:, None]), np.float64)
    if people.ndim == 3 and people.shape[1] > 1:
        near = 100.0 * np.hypot(*(p[:, None, :2] - people[frames + 1][:, :, :2]).transpose(2, 0, 1)).min(1)
        out.update({"nearest_person_median_cm": float(np.median(near)),
                    "nearest_person_p90_cm": float(np.percentile(near, 90))})
    return out


def with_walk(data: SampleData, frames: np.ndarray, positions: np.ndarray) -> SampleData:
    """A copy of ``data`` whose person positions are ``positions`` (float [F, 3] m) at the walk
    ``frames`` (int [F]) and unknown (NaN) at every other walk frame, and whose feature box is the
    dataset's bounds together with those positions (not the dataset's stated walk)."""
    import copy

    out = copy.copy(data)
    pp = np.array(data.person_pos, np.float64, copy=True)
    pp[data.states > 0] = np.nan
    for h, p in zip(np.asarray(frames), np.asarray(positions, np.float64)):
        pp[data.states == h + 1] = p
    out.person_pos = pp
    out.people_pos = pp[:, None, :]
    out.box = feature_box(*data.bounds, positions)
    return out


def write_walk(path: str | Path, rounds: list[dict], frames: np.ndarray) -> Path:
    """``walk.json``: every round's estimated walk (frames, positions, losses, error)."""
    return write_json_with_numpy(Path(path), {"frames": np.asarray(frames).tolist(), "rounds": rounds})
