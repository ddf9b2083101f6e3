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


def select(results: dict, *, dataset: str, method: str, snr=None, positions: int = 0) -> list[dict]:
    out = []
    for r in results.values():
        j = r["job"]
        if (j["dataset"] == dataset and j["method"] == method and j["positions"] == positions
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
DYN_NN = "eval.dynamic.nearest_neighbour.mean"
DYN_MI = "eval.dynamic.mean_image.mean"
STAT_NN = "eval.static.nearest_neighbour.mean"
STAT_MI = "eval.static.mean_image.mean"
AFF = "eval.affected.model.mean"
AFF_NN = "eval.affected.nearest_neighbour.mean"
AFF_EMPTY = "eval.affected.empty_room.mean"


class Claims:
    def __init__(self):
        self.rows = []

    def add(self, claim: str, paper_evidence: str, ours: str, holds):
        verdict = "n/a (not run)" if holds is None else ("**holds**" if holds else "**does not hold**")
        self.rows.append(f"| {claim} | {paper_evidence} | {ours} | {verdict} |")
