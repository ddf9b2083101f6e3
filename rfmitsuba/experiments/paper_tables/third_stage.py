"""Stage 3: does the walk improve the static scene, the background refined with the person field."""
from __future__ import annotations

from ..job import Job
from ..results import (
    AFF,
    AFF_NN,
    DYN,
    DYN_MI,
    DYN_NN,
    LABEL,
    STAT,
    STAT_MED,
    STAT_MI,
    STAT_NN,
    Claims,
    fmt,
    select,
)
from ..sizes import ExperimentConfig
from .base import Table, reference_dataset


class ThirdStageTable(Table):
    """Does the walk improve the static scene? Ours' background and person refined together on
    empty-room and walk data (method "refined", Stage 3) against Baseline, Continued and Ours on
    the first room and task. The paper's abstract says the walk improves the static scene; a
    frozen background cannot, so only a third stage can test it (coherent Gaussian family only)."""

    key = "third_stage"
    methods = ("baseline", "continued", "ours", "refined")

    def jobs(self, cfg: ExperimentConfig, seed: int) -> list[Job]:
        if cfg.train.model != "coherent_gaussians":
            return []
        return [Job(reference_dataset(cfg), m, seed) for m in self.methods]

    def section(self, cfg: ExperimentConfig, results: dict, claims: Claims) -> list[str]:
        room, task = cfg.rooms[0], cfg.tasks[0]
        ref = reference_dataset(cfg).key
        if cfg.train.model != "coherent_gaussians":
            return [f"## Does the walk improve the static scene? ({room}, moving {task.upper()})", "",
                    f"Not run: Stage 3 needs the coherent Gaussian family (train.model = 'coherent_gaussians'), "
                    f"this experiment trains {cfg.train.model!r}.", ""]
        L = [f"## Does the walk improve the static scene? ({room}, moving {task.upper()})", "",
             "Stage 3 (*Ours + Stage 3*) unfreezes Ours' background and trains it together with the person field "
             f"for {cfg.train.stage2_iterations} more steps on empty-room and walk samples, at Stage 1's final learning "
             "rates. Static = the background alone on the empty room's test positions.", "",
             "| method | steps | static mean | static median | dynamic mean | where the person matters |",
             "|---|---|---|---|---|---|"]
        rs = {m: select(results, dataset=ref, method=m) for m in self.methods}
        for m in self.methods:
            steps = fmt(rs[m], "train.steps", 0).split(" ±")[0]
            L.append(f"| {LABEL[m]} | {steps} | {fmt(rs[m], STAT)} | {fmt(rs[m], STAT_MED)} | {fmt(rs[m], DYN)} | "
                     f"{fmt(rs[m], AFF)} |")
        rb = rs["baseline"]
        L += [f"| *nearest neighbour / mean image* | | {fmt(rb, STAT_NN)} / {fmt(rb, STAT_MI)} | | "
              f"{fmt(rb, DYN_NN)} / {fmt(rb, DYN_MI)} | {fmt(rb, AFF_NN)} |", ""]
        claims.paired("The walk improves the static scene: Stage 3 beats Baseline (static)", "abstract", rs["refined"],
                      rb, STAT, names=("Stage 3", "Baseline"))
        claims.paired("... and beats training on the empty room longer (Continued, static)", "-", rs["refined"],
                      rs["continued"], STAT, names=("Stage 3", "Continued"))
        claims.paired("Stage 3 keeps Ours' dynamic gain (Stage 3 beats Ours, dynamic)", "-", rs["refined"], rs["ours"],
                      DYN, names=("Stage 3", "Ours"))
        return L
