"""The perturber's material: Baseline and Ours with the person's body as each material."""
from __future__ import annotations

from .. import paper
from ..job import Job
from ..results import (
    DYN,
    DYN_MED,
    Claims,
    fmt,
    paper_fmt,
    select,
)
from ..sizes import DatasetSpec, ExperimentConfig
from .base import Table


class MaterialTable(Table):
    """Perturber material: Baseline and Ours per material (paper Table `tab:material_properties`)."""

    key = "material"

    def jobs(self, cfg: ExperimentConfig, seed: int) -> list[Job]:
        room, task = cfg.rooms[0], cfg.tasks[0]
        return [Job(DatasetSpec(room, task, mat), m, seed) for mat in cfg.materials for m in ("baseline", "ours")]

    def section(self, cfg: ExperimentConfig, results: dict, claims: Claims) -> list[str]:
        room, task = cfg.rooms[0], cfg.tasks[0]
        L: list[str] = []
        L += [f"## Perturber material (paper Table `tab:material_properties`; {room}, moving {task.upper()})", "",
              "| material | Baseline dynamic mean | Ours dynamic mean | Ours dynamic median | paper Ours mean / median |",
              "|---|---|---|---|---|"]
        ours = {}
        for mat in cfg.materials:
            ds = DatasetSpec(room, task, mat).key
            rb, ro = select(results, dataset=ds, method="baseline"), select(results, dataset=ds, method="ours")
            ours[mat] = ro
            L.append(f"| {mat} | {fmt(rb, DYN)} | {fmt(ro, DYN)} | {fmt(ro, DYN_MED)} | {paper_fmt(paper.MATERIAL.get(mat))} |")
        L.append("")
        # the paper's order, one step at a time, each judged on its per-seed differences
        for hi, lo in (("concrete", "tissue"), ("tissue", "metal")):
            if ours.get(hi) and ours.get(lo):
                claims.paired(f"A {hi} perturber is easier than {lo} for Ours (dynamic)",
                              f"{paper.MATERIAL[hi][0]:.3f} vs {paper.MATERIAL[lo][0]:.3f}",
                              ours[hi], ours[lo], DYN, names=(hi, lo))
        return L
