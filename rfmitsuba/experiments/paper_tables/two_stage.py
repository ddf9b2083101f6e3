"""The two-stage ablation: Baseline, End-to-End, Continued and Ours on the first room and task."""
from __future__ import annotations

from .. import paper
from ..results import (
    DYN,
    LABEL,
    STAT,
    Claims,
    fmt,
    mean,
    mean_std_n,
    paper_fmt,
    select,
)
from ..sizes import ExperimentConfig
from .base import ReferenceTable, reference_dataset


class TwoStageTable(ReferenceTable):
    """Two-stage ablation: Baseline, End-to-End, Continued, Ours on the first room and task
    (paper Table `tab:ablation_strategy`)."""

    key = "two_stage"
    methods = ("baseline", "end_to_end", "continued", "ours")

    def section(self, cfg: ExperimentConfig, results: dict, claims: Claims) -> list[str]:
        room, task = cfg.rooms[0], cfg.tasks[0]
        ref = reference_dataset(cfg).key
        L: list[str] = []
        L += [f"## Two-stage ablation (paper Table `tab:ablation_strategy`; {room}, moving {task.upper()})", "",
              "| method | steps | dynamic mean | static mean | paper mean |", "|---|---|---|---|---|"]
        for m in self.methods:
            rs = select(results, dataset=ref, method=m)
            steps = fmt(rs, "train.steps", 0).split(" ±")[0]
            L.append(f"| {LABEL[m]} | {steps} | {fmt(rs, DYN)} | {fmt(rs, STAT)} | "
                     f"{paper_fmt(paper.TWO_STAGE.get(m, paper.PERTURBATION.get(m)))} |")
        L.append("")
        b, c = select(results, dataset=ref, method="baseline"), select(results, dataset=ref, method="continued")
        if b and c:
            d = mean(c, STAT) - mean(b, STAT)
            sd = max(mean_std_n(b, STAT)[1], mean_std_n(c, STAT)[1], 0.005)
            claims.add("Training the baseline longer gives no gain", "0.844 -> 0.844",
                       f"static {mean(b, STAT):.3f} -> {mean(c, STAT):.3f} (diff {d:+.3f}, std {sd:.3f})",
                       d <= sd)
        o, e = select(results, dataset=ref, method="ours"), select(results, dataset=ref, method="end_to_end")
        if o and e and b:
            claims.paired("Two-stage is needed: Ours beats End-to-End (dynamic)", "0.927 vs 0.858", o, e, DYN,
                          names=("Ours", "End-to-End"))
        return L
