"""The search over person positions: a coarse grid's best points, a descent from each (Dr.Jit AD,
or Nelder-Mead for a person field without gradients), a hop across the loss's fringes and a
polish (:func:`locate`, :func:`refine`)."""
from __future__ import annotations

import numpy as np

from ...core.errors import ConfigError
from .model import TwoStage
from .query import Query
from .region import SearchRegion


def _spread_starts(xy: np.ndarray, losses: np.ndarray, count: int, min_dist: float) -> np.ndarray:
    """Indices of the ``count`` lowest losses whose points are at least ``min_dist`` apart (greedy)."""
    order = np.argsort(losses, kind="stable")
    pick: list[int] = []
    for i in order:
        if all(np.hypot(*(xy[i] - xy[j])) >= min_dist for j in pick):
            pick.append(int(i))
            if len(pick) == count:
                break
    return np.asarray(pick, np.int64)


def wavelength(model: TwoStage) -> float:
    """The carrier wavelength [m] of the model's dataset."""
    from ...rf.array import SPEED_OF_LIGHT

    return SPEED_OF_LIGHT / float(model.data.frequency_hz)


def _hop(query: Query, region: SearchRegion, xs: np.ndarray, ls: np.ndarray, *, spacing: float):
    """The best of a 5 x 5 grid of ``spacing`` [m] centred on each point of ``xs`` (float [S, 2],
    losses ``ls`` [S]): a coherent field's loss has a minimum every half wavelength or so along a
    path (its fringes), and a descent ends in the one nearest its start, so the points a quarter
    and a half wavelength away on either side are tried. Returns (float64 [S, 2], float64 [S])."""
    off = spacing * np.stack(np.meshgrid(np.arange(-2, 3), np.arange(-2, 3), indexing="ij"), -1).reshape(-1, 2)
    off = off[np.any(off != 0, axis=1)]
    cand = (np.asarray(xs, np.float64)[:, None, :] + off[None]).reshape(-1, 2)
    ok = region.free(cand)
    cl = np.full(len(cand), np.inf)
    if ok.any():
        cl[ok] = query.losses(cand[ok])
    cl = cl.reshape(len(xs), len(off))
    j = np.argmin(cl, axis=1)
    best = cl[np.arange(len(xs)), j]
    take = best < ls
    out = np.asarray(xs, np.float64).copy()
    out[take] = cand.reshape(len(xs), len(off), 2)[np.arange(len(xs)), j][take]
    return out, np.where(take, best, ls)


def _descend_ad(query: Query, region: SearchRegion, starts: np.ndarray, *, steps: int, lr_m: float):
    """Adam on (x, y) from every start at once; a step out of the region is not taken. Returns the
    best (point float64 [S, 2], loss float64 [S]) met by each start."""
    x = np.asarray(starts, np.float64).copy()
    m1, m2 = np.zeros_like(x), np.zeros_like(x)
    b1, b2, eps = 0.9, 0.999, 1e-12
    best_x, best_l = x.copy(), np.full(len(x), np.inf)
    for t in range(1, steps + 1):
        loss, g = query.loss_and_grad(x)
        better = loss < best_l
        best_x[better], best_l[better] = x[better], loss[better]
        if t == steps:
            break
        lr = lr_m * (0.1 ** ((t - 1) / max(steps - 1, 1)))
        m1 = b1 * m1 + (1 - b1) * g
        m2 = b2 * m2 + (1 - b2) * g * g
        step = lr * (m1 / (1 - b1 ** t)) / (np.sqrt(m2 / (1 - b2 ** t)) + eps)
        new = x - step
        ok = region.free(new)
        x[ok] = new[ok]
    return best_x, best_l


def _descend_nelder_mead(query: Query, region: SearchRegion, starts: np.ndarray, *, steps: int, simplex_m: float):
    """SciPy's bounded Nelder-Mead from every start (at most ``4 * steps`` losses each; a point out
    of the region costs 10). Returns the best (point float64 [S, 2], loss float64 [S])."""
    from scipy.optimize import minimize

    def f(v):
        return float(query.losses(v[None])[0]) if region.free(v[None])[0] else 10.0

    best_x, best_l = [], []
    for s in np.asarray(starts, np.float64):
        simplex = np.stack([s, s + [simplex_m, 0.0], s + [0.0, simplex_m]])
        r = minimize(f, s, method="Nelder-Mead", bounds=list(zip(region.lo, region.hi)),
                     options={"maxfev": 4 * steps, "xatol": 0.005, "fatol": 1e-6, "initial_simplex": simplex})
        best_x.append(r.x if r.fun <= f(s) else s)
        best_l.append(min(r.fun, f(s)))
    return np.asarray(best_x), np.asarray(best_l)


def refine(query: Query, region: SearchRegion, starts: np.ndarray, *, steps: int = 30, lr_m: float = 0.03,
           grid_m: float = 0.25, descent: str = "ad") -> tuple[np.ndarray, np.ndarray]:
    """Descend from each start, hop to the best neighbouring fringe, descend again (the search of
    :func:`locate` after its grid).

    Args:
        query: what is compared; region: where the feet may be; starts: float [S, 2] (x, y) [m];
        steps: descent steps (AD) or a quarter of the losses per start (Nelder-Mead); lr_m: first
        AD step [m]; grid_m: the grid spacing the starts came from [m] (Nelder-Mead's simplex);
        descent: "ad" or "nelder_mead".

    Returns:
        (float64 [S, 2] the best point met from each start, float64 [S] its loss).
    """
    hop = wavelength(query.model) / 4

    def descend(x0, n, scale):
        if descent == "ad":
            return _descend_ad(query, region, x0, steps=n, lr_m=scale)
        return _descend_nelder_mead(query, region, x0, steps=n, simplex_m=scale)

    xs, ls = descend(np.asarray(starts, np.float64).reshape(-1, 2), steps, lr_m if descent == "ad" else 0.5 * grid_m)
    hx, hl = _hop(query, region, xs, ls, spacing=hop)                  # the best neighbouring fringe
    px, pl = descend(hx, max(1, steps // 3), lr_m / 3 if descent == "ad" else hop / 2)
    return np.where((pl < hl)[:, None], px, hx), np.minimum(pl, hl)


def locate(model: TwoStage, pas: np.ndarray, positions: np.ndarray, *, grid_m: float = 0.25, starts: int = 4,
           steps: int = 30, lr_m: float = 0.03, loss: str = "train", downsample: int = 2, region: str = "walk",
           descent: str = "auto", search: SearchRegion | None = None, empty: np.ndarray | None = None,
           score_at: np.ndarray | None = None) -> dict:
    """Where the person stands, from PAS taken at ``positions`` (see the module docstring).

    Args:
        model: :func:`open_two_stage`'s model; pas: float [K, 90, 360] or [90, 360]; positions:
            float [K, 3] or [3] the moving device [m]; grid_m: coarse grid spacing [m]; starts:
            descent starts; steps: descent steps (AD) or a quarter of the losses per start
            (Nelder-Mead); lr_m: first AD step [m]; loss: "train" or "ssim"; downsample: block size;
            region: "walk" or "room" (:meth:`SearchRegion.of`); descent: "auto" (AD where
            the person field allows it, else Nelder-Mead), "ad", "nelder_mead" or "none" (the grid
            alone); search: a region made before (``region`` is then ignored); empty: None, or the
            empty room's PAS at ``positions`` (float [K, 90, 360]): the model's change is then
            fitted on top of them (:class:`Query`); score_at: None, or feet positions float [M, 2 or
            3] [m] whose losses are returned too (e.g. the true one).

    Returns:
        {"position": float64 [3] feet [m], "loss": float, "grid_position": float64 [3] the best
        grid point, "grid_loss": float, "descent": the kind used, "reference": "empty" or "none",
        "loss_without_person": the background alone's loss, "losses_at": float64 [M] (with
        ``score_at``), "losses_evaluated": int, "views": K}.
    """
    if descent not in ("auto", "ad", "nelder_mead", "none"):
        raise ConfigError(f"descent must be 'auto', 'ad', 'nelder_mead' or 'none', got {descent!r}")
    if starts < 1 or steps < 1:
        raise ConfigError(f"starts and steps must be >= 1, got {starts} and {steps}")
    if descent == "ad" and not model.differentiable:
        raise ConfigError(f"descent 'ad' needs a person field differentiable in the position; "
                          f"{type(model.person).__name__} is not (use 'nelder_mead')")
    kind = ("ad" if model.differentiable else "nelder_mead") if descent == "auto" else descent
    reg = search or SearchRegion.of(model, region=region)
    q = Query(model, pas, positions, loss=loss, downsample=downsample, empty=empty)
    grid = reg.grid(grid_m)
    gl = q.losses(grid)
    best = int(np.argmin(gl))
    pick = _spread_starts(grid, gl, starts, 2 * grid_m)
    if kind == "none":
        xs, ls = grid[pick], gl[pick]
    else:
        xs, ls = refine(q, reg, grid[pick], steps=steps, lr_m=lr_m, grid_m=grid_m, descent=kind)
    i = int(np.argmin(ls))
    x, lo = (xs[i], float(ls[i])) if ls[i] <= gl[best] else (grid[best], float(gl[best]))
    out = {"position": reg.feet(x)[0], "loss": lo, "grid_position": reg.feet(grid[best])[0],
           "grid_loss": float(gl[best]), "descent": kind, "reference": q.reference,
           "loss_without_person": q.loss_without_person(), "losses_evaluated": int(q.evaluations), "views": q.k}
    if score_at is not None:
        out["losses_at"] = q.losses(np.asarray(score_at, np.float64).reshape(len(score_at), -1)[:, :2])
    return out
