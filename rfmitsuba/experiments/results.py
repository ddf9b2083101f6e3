"""Selecting and formatting the results of a reproduction's jobs.

``results`` = {"<dataset>/<job>": metrics of :func:`rfmitsuba.experiments.reproduce.reproduce_job`}, each
with ``job`` (its :meth:`rfmitsuba.experiments.job.Job.record`), ``train`` and ``eval``.
:func:`select` picks the jobs of one configuration, :func:`value` reads a dotted path of one,
:func:`mean_std_n` / :func:`fmt` / :func:`mean` summarise a path over seeds; the path constants
(``DYN``, ``STAT``, ...) name the figures the tables report; :class:`Claims` collects the
verdicts on the paper's claims.
"""
from __future__ import annotations

import math

import numpy as np

from .methods import METHODS

LABEL = {k: m.label for k, m in METHODS.items()}


def select(results: dict, *, dataset: str, method: str, snr=None, positions: int = 0,
           eval_dataset: str | None = None, layout: str = "random", walk_frames: int | None = None) -> list[dict]:
    """The jobs trained on ``dataset`` by ``method`` at noise ``snr`` (None = clean) with
    ``positions`` training positions (0 = all) laid out by ``layout``, on the first ``walk_frames``
    walk positions (None = the whole walk), evaluated on ``eval_dataset`` (None = ``dataset``)."""
    out = []
    for r in results.values():
        j = r["job"]
        if (j["dataset"] == dataset and j["method"] == method and j["positions"] == positions
                and j.get("layout", "random") == layout and j.get("walk_frames") == walk_frames
                and j.get("eval_dataset", j["dataset"]) == (eval_dataset or dataset)
                and (j["snr_db"] == "none" if snr is None else j["snr_db"] == float(snr))):
            out.append(r)
    return out


def value(r: dict, path: str):
    v = r
    for p in path.split("."):
        if v is None:
            return None
        v = v.get(p) if isinstance(v, dict) else None
    return v


def values(rs: list[dict], path: str) -> list[float]:
    return [float(value(r, path)) for r in rs if value(r, path) is not None]


def mean_std_n(rs, path) -> tuple[float, float, int]:
    v = [x for x in values(rs, path) if math.isfinite(x)]
    if not v:
        return float("nan"), float("nan"), 0
    return float(np.mean(v)), (float(np.std(v, ddof=1)) if len(v) > 1 else 0.0), len(v)


def fmt(rs, path, digits: int = 3) -> str:
    m, s, n = mean_std_n(rs, path)
    if n == 0:
        return "-"
    return f"{m:.{digits}f} ± {s:.{digits}f}"


def mean(rs, path) -> float:
    return mean_std_n(rs, path)[0]


def paper_fmt(x) -> str:
    if x is None:
        return "-"
    if isinstance(x, tuple):
        return " / ".join(f"{v:.3f}" for v in x)
    return f"{x:.3f}"


DYN = "eval.dynamic.model.mean"
DYN_MED = "eval.dynamic.model.median"
STAT = "eval.static.model.mean"
STAT_MED = "eval.static.model.median"
#: the background at its own training positions (the generalisation gap is STAT_FIT - STAT)
STAT_FIT = "eval.static.fit.mean"
DYN_NN = "eval.dynamic.nearest_neighbour.mean"
DYN_MI = "eval.dynamic.mean_image.mean"
DYN_IDW = "eval.dynamic.idw3.mean"
#: floors from the noisy training PAS a noise-table job trained on (evaluate(noise_snr_db=...))
DYN_NN_NOISY = "eval.dynamic.floors_noisy_training.nearest_neighbour.mean"
DYN_IDW_NOISY = "eval.dynamic.floors_noisy_training.idw3.mean"
STAT_NN_NOISY = "eval.static.floors_noisy_training.nearest_neighbour.mean"
STAT_IDW_NOISY = "eval.static.floors_noisy_training.idw3.mean"
STAT_NN = "eval.static.nearest_neighbour.mean"
STAT_IDW = "eval.static.idw3.mean"
STAT_MI = "eval.static.mean_image.mean"
AFF = "eval.affected.model.mean"
AFF_NN = "eval.affected.nearest_neighbour.mean"
AFF_EMPTY = "eval.affected.empty_room.mean"


class Claims:
    """The report's verdicts on the paper's claims: Markdown table rows (claim, paper, ours, verdict)."""

    def __init__(self):
        self.rows = []

    def add(self, claim: str, paper_evidence: str, ours: str, holds):
        """A verdict decided by the caller: ``holds`` True, False, None (not run) or "unclear"."""
        verdict = {None: "n/a (not run)", "unclear": "**unclear**", True: "**holds**", False: "**does not hold**"}[holds]
        self.rows.append(f"| {claim} | {paper_evidence} | {ours} | {verdict} |")

    def paired(self, claim: str, paper_evidence: str, a: list[dict], b: list[dict], path: str, *,
               names: tuple[str, str]) -> None:
        """The claim "a scores higher than b on ``path``", judged on the per-seed differences of the
        seeds both ran: the effect is their mean, the spread their sample std. It **holds** when
        every seed's difference is positive and the effect exceeds the spread, **does not hold**
        when no seed's difference is positive or the effect is below minus the spread, and is
        **unclear** otherwise (also with fewer than 2 seeds)."""
        v = paired_verdict(a, b, path)
        if v is None:
            self.add(claim, paper_evidence, "-", None)
            return
        d = v["per_seed"]
        self.add(claim, paper_evidence,
                 f"{names[0]} {v['a']:.3f} vs {names[1]} {v['b']:.3f}: effect {format_effect(v)} "
                 f"over {len(d)} seeds (per seed {', '.join(f'{x:+.3f}' for x in d)})", v["holds"])


#: the floors a result is listed below (the data-scarce table's list, the report's "Where methods
#: break"): per evaluation part, the model's path and its floors' (name, path, path on the noisy
#: training data), in the order a listed result names them
BELOW_FLOORS = {"static": (STAT, (("IDW-3", STAT_IDW, STAT_IDW_NOISY), ("NN", STAT_NN, STAT_NN_NOISY))),
                "dynamic": (DYN, (("IDW-3", DYN_IDW, DYN_IDW_NOISY), ("NN", DYN_NN, DYN_NN_NOISY)))}


def format_below(value: float, floors: list[tuple[str, float]]) -> str:
    """A result below floors as text, "0.617 < IDW-3 0.663, NN 0.621": ``floors`` [(name, value)],
    printed with the fewest digits, 3 to 6, that tell the result from every floor (three would
    print 0.65916 against 0.65920 as equal)."""
    d = next((k for k in range(3, 6) if all(f"{value:.{k}f}" != f"{f:.{k}f}" for _, f in floors)), 6)
    return f"{value:.{d}f} < " + ", ".join(f"{name} {f:.{d}f}" for name, f in floors)


def format_effect(verdict: dict) -> str:
    """A :func:`paired_verdict`'s effect as text, "+0.004 ± 0.002" (three decimals, signed); the
    spread is left out where it is undefined (one seed)."""
    spread = verdict["spread"]
    return f"{verdict['effect']:+.3f}" + ("" if math.isnan(spread) else f" ± {spread:.3f}")


def paired_verdict(a: list[dict], b: list[dict], path: str) -> dict | None:
    """The paired rule of :meth:`Claims.paired` on ``path`` of jobs ``a`` against jobs ``b``: None
    when no seed ran both, else {"holds": True / False / "unclear", "effect": mean per-seed
    difference, "spread": its sample std (NaN for one seed), "per_seed": the differences [seeds],
    "a" / "b": the means over those seeds}."""
    va = {r["job"]["seed"]: value(r, path) for r in a if value(r, path) is not None}
    vb = {r["job"]["seed"]: value(r, path) for r in b if value(r, path) is not None}
    seeds = sorted(set(va) & set(vb))
    if not seeds:
        return None
    d = np.array([va[s] - vb[s] for s in seeds], np.float64)
    eff, sd = float(d.mean()), (float(d.std(ddof=1)) if len(d) > 1 else float("nan"))
    if len(d) < 2:
        holds = "unclear"
    elif (d > 0).all() and eff > sd:
        holds = True
    elif (d <= 0).all() or eff < -sd:
        holds = False
    else:
        holds = "unclear"
    return {"holds": holds, "effect": eff, "spread": sd, "per_seed": [float(x) for x in d],
            "a": float(np.mean([va[s] for s in seeds])), "b": float(np.mean([vb[s] for s in seeds]))}
