"""The number of training positions: Baseline and Ours at each count."""
from __future__ import annotations

import math

from .. import paper
from ..job import Job
from ..results import (
    DYN,
    STAT,
    STAT_MED,
    STAT_NN,
    Claims,
    fmt,
    mean,
    paper_fmt,
    select,
)
from ..sizes import ExperimentConfig
from .base import Table, reference_dataset


class PositionsTable(Table):
    """Number of training positions: Baseline and Ours at each count (paper Table `tab:motivation`)."""

    key = "positions"

    def jobs(self, cfg: ExperimentConfig, seed: int) -> list[Job]:
        return [Job(reference_dataset(cfg), m, seed, positions=n) for n in list(cfg.position_counts) + [0]
                for m in ("baseline", "ours")]

    def section(self, cfg: ExperimentConfig, results: dict, claims: Claims) -> list[str]:
        room, task = cfg.rooms[0], cfg.tasks[0]
        ref = reference_dataset(cfg).key
        L: list[str] = []
        L += [f"## Number of training positions (paper Table `tab:motivation`; {room}, moving {task.upper()})", "",
              "| training antenna positions | Baseline static mean | Baseline static median | Ours dynamic mean | "
              "static NN floor |", "|---|---|---|---|---|"]
        series = []
        counts = sorted(set(cfg.position_counts)) + [0]
        for n in counts:
            rb = select(results, dataset=ref, method="baseline", positions=n)
            ro = select(results, dataset=ref, method="ours", positions=n)
            label = str(n) if n else f"all ({int(round(cfg.data.positions * 0.8))})"
            series.append(mean(rb, STAT))
            L.append(f"| {label} | {fmt(rb, STAT)} | {fmt(rb, STAT_MED)} | {fmt(ro, DYN)} | {fmt(rb, STAT_NN)} |")
        L += ["", "Paper (Baseline, empty room, 900 to 10000 RX locations): "
              + ", ".join(f"{k}: {paper_fmt(v)}" for k, v in paper.POSITIONS.items()), ""]
        ok = [x for x in series if math.isfinite(x)]
        if len(ok) >= 2:
            claims.add("More static positions improve the baseline", "0.844 (900) -> 0.929 (10000)",
                       " -> ".join(f"{x:.3f}" for x in ok), all(b >= a - 0.005 for a, b in zip(ok, ok[1:])))
        return L
