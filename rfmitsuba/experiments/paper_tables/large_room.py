"""The large room against the first room: where Ours overfits, the background's fit against
its test score, and the error by distance."""
from __future__ import annotations

from pathlib import Path

from ...eval.breakdown import DISTANCES
from ...eval.dynamic_static import FIT_POSITIONS
from .. import paper
from ..job import Job
from ..results import (
    DYN,
    DYN_NN,
    STAT,
    STAT_FIT,
    STAT_NN,
    Claims,
    fmt,
    mean,
    paper_fmt,
    select,
    value,
)
from ..sizes import DatasetSpec, ExperimentConfig
from .base import Table


class LargeRoomTable(Table):
    """Large room against the first room, moving RX: where Ours overfits (paper Table
    `tab:large_scene_limitations`), the background's fit against its test score, and where it
    breaks (static SSIM by distance to the fixed device and to the nearest training position)."""

    key = "large_room"

    def jobs(self, cfg: ExperimentConfig, seed: int) -> list[Job]:
        if not cfg.large_room:
            return []
        return [Job(DatasetSpec(sc, "rx"), m, seed) for sc in (cfg.large_room, cfg.rooms[0]) for m in ("baseline", "ours")]

    def section(self, cfg: ExperimentConfig, results: dict, claims: Claims) -> list[str]:
        room = cfg.rooms[0]
        L: list[str] = []
        L += ["## Large room (paper Table `tab:large_scene_limitations`, moving RX)", "",
              "| scene | Baseline dynamic mean | Ours test (dynamic) | Ours val (Stage-2 validation) | "
              "NN floor | paper Baseline / Ours test / Ours val |", "|---|---|---|---|---|---|"]
        for sc in (room, cfg.large_room):
            ds = DatasetSpec(sc, "rx").key
            rb, ro = select(results, dataset=ds, method="baseline"), select(results, dataset=ds, method="ours")
            L.append(f"| {paper.ROOM_LABELS.get(sc, sc)} | {fmt(rb, DYN)} | {fmt(ro, DYN)} | {fmt(ro, 'train.val_ssim')} | "
                     f"{fmt(rb, DYN_NN)} | {paper_fmt(paper.LARGE_ROOM.get(sc))} |")
        L.append("")
        L += ["The background (Baseline, empty room) at its own training positions against unseen ones "
              f"(fit: {FIT_POSITIONS} training positions, evenly spaced; a large gap is overfitting):", "",
              "| scene | static fit (training positions) | static test | gap | static NN |", "|---|---|---|---|---|"]
        for sc in (room, cfg.large_room):
            rb = select(results, dataset=DatasetSpec(sc, "rx").key, method="baseline")
            gap = [value(r, STAT_FIT) - value(r, STAT) for r in rb
                   if value(r, STAT_FIT) is not None and value(r, STAT) is not None]
            gap_s = "-" if not gap else f"{sum(gap) / len(gap):+.3f}"
            L.append(f"| {paper.ROOM_LABELS.get(sc, sc)} | {fmt(rb, STAT_FIT)} | {fmt(rb, STAT)} | {gap_s} | "
                     f"{fmt(rb, STAT_NN)} |")
        L.append("")
        L += self._where_it_breaks(cfg, results)
        ds = DatasetSpec(cfg.large_room, "rx").key
        rb, ro = select(results, dataset=ds, method="baseline"), select(results, dataset=ds, method="ours")
        if rb and ro:
            claims.add("In the large room Ours overfits: test below Baseline, validation far above test",
                       "test 0.731 < Baseline 0.866; val 0.928",
                       f"test {mean(ro, DYN):.3f} vs Baseline {mean(rb, DYN):.3f}; val {mean(ro, 'train.val_ssim'):.3f}",
                       mean(ro, DYN) < mean(rb, DYN) and mean(ro, "train.val_ssim") > mean(ro, DYN))
        return L

    @staticmethod
    def _binned(rs: list[dict], distance: str) -> dict | None:
        """Seed mean of the static part's breakdown over ``distance``: {"edges", "model",
        "nearest_neighbour"} (the test positions, so the bins, are the dataset's, the same for
        every seed); None when no job recorded it."""
        parts = [value(r, f"eval.static.by_distance.{distance}") for r in rs]
        parts = [p for p in parts if p]
        if not parts or any(p["edges"] != parts[0]["edges"] for p in parts):
            return None
        avg = {k: [sum(p[k][b] for p in parts) / len(parts) for b in range(len(parts[0][k]))]
               for k in ("model", "nearest_neighbour")}
        return {"edges": parts[0]["edges"], **avg}

    def _where_it_breaks(self, cfg: ExperimentConfig, results: dict) -> list[str]:
        L: list[str] = []
        rows = []
        for sc in (cfg.rooms[0], cfg.large_room):
            rb = select(results, dataset=DatasetSpec(sc, "rx").key, method="baseline")
            for dist, label in DISTANCES.items():
                b = self._binned(rb, dist)
                if b:
                    cells = [f"{lo:.2f}–{hi:.2f} m: **{m:.3f}** / {n:.3f}" for lo, hi, m, n in
                             zip(b["edges"][:-1], b["edges"][1:], b["model"], b["nearest_neighbour"])]
                    rows.append(f"| {paper.ROOM_LABELS.get(sc, sc)} | distance {label} | " + " | ".join(cells) + " |")
        if rows:
            L += ["Where it breaks: the Baseline's static test SSIM (**bold**) against nearest neighbour, by "
                  "quartile of a distance (mean over seeds):", "",
                  "| scene | by | 1st quartile | 2nd | 3rd | 4th |", "|---|---|---|---|---|---|", *rows, ""]
        return L

    def figures(self, out: Path, cfg: ExperimentConfig, results: dict) -> list[str]:
        """``large_room.png``: the Baseline's static SSIM and the nearest-neighbour floor per quartile
        of each distance (:data:`rfmitsuba.eval.breakdown.DISTANCES`), the first room against the large one; nothing when
        no job recorded the breakdown."""
        from ...core import plots

        if not cfg.large_room:
            return []
        rooms = [(sc, select(results, dataset=DatasetSpec(sc, "rx").key, method="baseline"))
                 for sc in (cfg.rooms[0], cfg.large_room)]
        if not any(self._binned(rb, d) for _, rb in rooms for d in DISTANCES):
            return []
        fig, axes = plots.subplots(1, len(DISTANCES), figsize=(4.8 * len(DISTANCES), 3.6), squeeze=False)
        for ax, (dist, label) in zip(axes[0], DISTANCES.items()):
            for (sc, rb), color in zip(rooms, ("tab:blue", "tab:red")):
                b = self._binned(rb, dist)
                if not b:
                    continue
                x = [(lo + hi) / 2 for lo, hi in zip(b["edges"][:-1], b["edges"][1:])]
                name = paper.ROOM_LABELS.get(sc, sc)
                ax.plot(x, b["model"], "o-", color=color, label=f"{name}: Baseline")
                ax.plot(x, b["nearest_neighbour"], "s--", color=color, alpha=0.6, label=f"{name}: NN")
            plots.label(ax, xlabel=f"distance {label} (m), quartile centre", ylabel="static test SSIM (mean over seeds)",
                        legend_fontsize=7)
        plots.save(fig, Path(out) / "large_room.png")
        return ["![Where the background breaks, by distance](large_room.png)", ""]
