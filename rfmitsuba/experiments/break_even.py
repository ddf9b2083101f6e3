"""How many static positions a walk is worth, read off two curves of score over static positions.

The data-scarce table (:class:`rfmitsuba.experiments.paper_tables.DataScarceTable`) measures the
static SSIM at a few counts of static training positions, without the walk and with it. At
``at`` static positions the walk lifts the score to ``s``; the static-only curve reaches ``s`` at
``n*`` positions, found between the two neighbouring counts where it first climbs past ``s``
(linear in log positions). The walk is worth ``n* - at`` static positions there
(:func:`positions_worth`), 0 where it does not lift the score, and more than the largest count
minus ``at`` where the static-only curve never gets there (returned as infinity).
:func:`worth_over_seeds` does it per seed and summarises the spread.
"""
from __future__ import annotations

import math

import numpy as np

from ..core.errors import ConfigError


def equivalent_positions(counts, without, score: float, *, start: int = 0) -> float:
    """Static positions at which the static-only curve first reaches ``score``.

    Args:
        counts: int [C] static positions, ascending, >= 1.
        without: float [C] the static-only score at each count.
        score: the score to reach.
        start: index into ``counts`` to search from (the curve is read from there up).

    Returns:
        The count where ``without`` first reaches ``score`` at or after ``counts[start]``,
        interpolated linearly in log positions between the two counts around the crossing;
        ``counts[start]`` when it is reached there already; infinity when never.
    """
    c = np.asarray(counts, np.float64)
    y = np.asarray(without, np.float64)
    if c.ndim != 1 or c.shape != y.shape or len(c) == 0 or (c < 1).any() or (np.diff(c) <= 0).any():
        raise ConfigError(f"equivalent_positions: counts must be ascending >= 1 and match the scores, got "
                          f"{list(c)} and {list(y)}")
    if y[start] >= score:
        return float(c[start])
    for i in range(start, len(c) - 1):
        if y[i + 1] >= score:
            t = (score - y[i]) / (y[i + 1] - y[i])       # y[i] < score <= y[i + 1]
            return float(math.exp(math.log(c[i]) + t * (math.log(c[i + 1]) - math.log(c[i]))))
    return math.inf


def positions_worth(counts, without, with_walk, *, at: int) -> float:
    """Static positions the walk is worth at ``at`` static positions.

    Args:
        counts: int [C] static positions, ascending; ``at`` must be one of them.
        without: float [C] the score of the static positions alone.
        with_walk: float [C] the score of the same positions plus the walk.
        at: the static positions the walk is added to.

    Returns:
        ``n* - at`` where ``n*`` (:func:`equivalent_positions`) is where ``without`` reaches
        ``with_walk`` at ``at``; 0.0 where the walk does not lift the score; infinity where the
        static-only curve never reaches it within ``counts``.
    """
    counts = [int(n) for n in counts]
    if at not in counts:
        raise ConfigError(f"positions_worth: at = {at} is not one of the counts {counts}")
    i = counts.index(at)
    s = float(np.asarray(with_walk, np.float64)[i])
    if s <= float(np.asarray(without, np.float64)[i]):
        return 0.0
    return equivalent_positions(counts, without, s, start=i) - at


def worth_over_seeds(counts, without: dict, with_walk: dict, *, at: int) -> dict:
    """:func:`positions_worth` for each seed both curves have in full.

    Args:
        counts: int [C] static positions, ascending.
        without / with_walk: seed -> float [C] scores (a seed missing a count, or NaN, is left out).
        at: one of ``counts``.

    Returns:
        {"per_seed": {seed: worth}, "mean", "std" (sample std; over the seeds, NaN where fewer
        than two or any is infinite), "beyond": seeds whose worth is infinite, "largest": the
        largest count minus ``at`` (the most a finite worth can be)}.
    """
    per = {}
    for seed in sorted(set(without) & set(with_walk)):
        a, b = np.asarray(without[seed], np.float64), np.asarray(with_walk[seed], np.float64)
        if len(a) == len(b) == len(counts) and np.isfinite(a).all() and np.isfinite(b).all():
            per[seed] = positions_worth(counts, a, b, at=at)
    v = np.array(list(per.values()), np.float64)
    finite = bool(len(v)) and bool(np.isfinite(v).all())
    return {"per_seed": per, "mean": float(v.mean()) if finite else math.nan,
            "std": float(v.std(ddof=1)) if finite and len(v) > 1 else math.nan,
            "beyond": [s for s, w in per.items() if math.isinf(w)], "largest": int(max(counts)) - int(at)}


def format_worth(w: dict) -> str:
    """A :func:`worth_over_seeds` result as text: "18 ± 4 (per seed 15, 22, 17)", "> 220 on 2 of 3
    seeds (per seed ...)" or "-" without seeds."""
    per = w["per_seed"]
    if not per:
        return "-"
    seeds = ", ".join("> " + str(w["largest"]) if math.isinf(x) else f"{x:.0f}" for x in per.values())
    if w["beyond"]:
        return f"> {w['largest']} on {len(w['beyond'])} of {len(per)} seeds (per seed {seeds})"
    sd = "" if math.isnan(w["std"]) else f" ± {w['std']:.0f}"
    return f"{w['mean']:.0f}{sd} (per seed {seeds})"
