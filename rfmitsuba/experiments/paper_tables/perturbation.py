"""The role of the perturbation data: Baseline, Duplicated, Baseline (person) and Ours."""
from __future__ import annotations

from .. import paper
from ..results import (
    DYN,
    LABEL,
    STAT,
    Claims,
    fmt,
    mean,
    paper_fmt,
    select,
)
from ..sizes import ExperimentConfig
from .base import ReferenceTable, reference_dataset


class PerturbationTable(ReferenceTable):
    """Role of perturbation data: Baseline, Duplicated, Baseline (person), Ours (paper Table `tab:ablation_info`)."""

    key = "perturbation"
    methods = ("baseline", "duplicated", "baseline_person", "ours")

    def section(self, cfg: ExperimentConfig, results: dict, claims: Claims) -> list[str]:
        room, task = cfg.rooms[0], cfg.tasks[0]
        ref = reference_dataset(cfg).key
        L: list[str] = []
        L += [f"## Role of perturbation data (paper Table `tab:ablation_info`; {room}, moving {task.upper()})", "",
              "| method | dynamic mean | static mean | paper mean |", "|---|---|---|---|"]
        for m in self.methods:
            rs = select(results, dataset=ref, method=m)
            L.append(f"| {LABEL[m]} | {fmt(rs, DYN)} | {fmt(rs, STAT)} | {paper_fmt(paper.PERTURBATION.get(m))} |")
        L.append("")
        b, du, h, o = (select(results, dataset=ref, method=m) for m in self.methods)
        if b and du:
            claims.add("Duplicating the empty data collapses the baseline", "0.844 -> 0.761",
                       f"static {mean(b, STAT):.3f} -> {mean(du, STAT):.3f}", mean(du, STAT) < mean(b, STAT) - 0.02)
        if b and h:
            claims.paired("Person-present data (no position) improves the background model (static)",
                          "0.844 -> 0.895", h, b, STAT, names=("Baseline (person)", "Baseline"))
        if h and o:
            claims.paired("Ours beats Baseline (person) (dynamic)", "0.927 vs 0.895", o, h, DYN,
                          names=("Ours", "Baseline (person)"))
        return L
