"""The Rx-count table: does one walk beat more static positions?"""
from __future__ import annotations

import math
from pathlib import Path

from .. import paper
from ..job import Job
from ..results import (
    AFF,
    AFF_NN,
    DYN,
    DYN_MI,
    DYN_NN,
    STAT,
    STAT_MI,
    STAT_NN,
    Claims,
    fmt,
    mean,
    mean_std_n,
    paper_fmt,
    select,
)
from ..sizes import DatasetSpec, ExperimentConfig
from .base import Table


def static_positions_for(train_positions: int) -> int:
    """Antenna positions of a dataset whose training split (80%, docs/conventions.md) holds at
    least ``train_positions``."""
    from ...data.split import ANTENNA_TEST_FRACTION

    n = int(math.ceil(train_positions / (1.0 - ANTENNA_TEST_FRACTION)))
    while n - int(round(ANTENNA_TEST_FRACTION * n)) < train_positions:
        n += 1
    return n


class RxCountTable(Table):
    """Does one walk beat more static positions? Baseline trained on the main dataset's positions
    and on ``cfg.rx_counts`` positions of an extra empty-room dataset, against Ours on the main
    dataset's positions plus the walk, all tested on the main dataset's test positions (paper
    Table `tab:motivation` and its claim that Ours beats a Baseline with 6000 positions). Rooms:
    the first two of ``cfg.rooms``, every task."""

    key = "rx_count"

    def _pairs(self, cfg: ExperimentConfig):
        n = static_positions_for(max(cfg.rx_counts))
        return [(DatasetSpec(r, k), DatasetSpec(r, k, static_positions=n)) for r in cfg.rooms[:2] for k in cfg.tasks]

    def jobs(self, cfg: ExperimentConfig, seed: int) -> list[Job]:
        out = []
        for main, extra in self._pairs(cfg):
            out += [Job(main, "baseline", seed), Job(main, "ours", seed)]
            out += [Job(extra, "baseline", seed, positions=n, eval_dataset=main) for n in sorted(cfg.rx_counts)]
        return out

    def section(self, cfg: ExperimentConfig, results: dict, claims: Claims) -> list[str]:
        from ...data.split import ANTENNA_TEST_FRACTION

        own = cfg.data.positions - int(round(ANTENNA_TEST_FRACTION * cfg.data.positions))
        L = ["## Static positions against one walk (paper Table `tab:motivation`)", "",
             f"Baseline trained on {own} positions (the main dataset's training split) and on "
             f"{', '.join(str(n) for n in sorted(cfg.rx_counts))} positions of an extra empty-room dataset of the "
             f"same room ({static_positions_for(max(cfg.rx_counts))} positions, another position seed); Ours on the "
             f"{own} positions plus the walk ({cfg.data.person_positions} positions). All are tested on the main "
             "dataset's test positions; the floors are the main dataset's (from its training split).", "",
             "| scene | task | method | training positions | static mean | dynamic mean | where the person matters |",
             "|---|---|---|---|---|---|---|"]
        for main, extra in self._pairs(cfg):
            room, task = paper.ROOM_LABELS.get(main.scene, main.scene), f"moving {main.task.upper()}"
            rb = select(results, dataset=main.key, method="baseline")
            series = [(own, rb)] + [(n, select(results, dataset=extra.key, method="baseline", positions=n,
                                               eval_dataset=main.key)) for n in sorted(cfg.rx_counts)]
            for n, rs in series:
                L.append(f"| {room} | {task} | Baseline | {n} | {fmt(rs, STAT)} | {fmt(rs, DYN)} | {fmt(rs, AFF)} |")
            ro = select(results, dataset=main.key, method="ours")
            L.append(f"| {room} | {task} | Ours | {own} + walk | {fmt(ro, STAT)} | {fmt(ro, DYN)} | {fmt(ro, AFF)} |")
            L.append(f"| | | *nearest neighbour / mean image* | {own} | {fmt(rb, STAT_NN)} / {fmt(rb, STAT_MI)} | "
                     f"{fmt(rb, DYN_NN)} / {fmt(rb, DYN_MI)} | {fmt(rb, AFF_NN)} |")
            top_n, top = series[-1]
            claims.paired(f"Ours ({own} positions + walk) beats Baseline with {top_n} positions ({room}, {task}, "
                          "dynamic)", "0.927 vs 0.920 (6000)", ro, top, DYN, names=("Ours", f"Baseline {top_n}"))
            claims.paired(f"Ours beats Baseline with {top_n} positions where the person matters ({room}, {task})",
                          "-", ro, top, AFF, names=("Ours", f"Baseline {top_n}"))
            claims.paired(f"{top_n} static positions improve the Baseline over {own} ({room}, {task}, static)",
                          "0.844 (900) -> 0.920 (6000)", top, rb, STAT, names=(f"Baseline {top_n}", f"Baseline {own}"))
        L += ["", "Paper (Baseline, empty room, bedroom, moving RX): "
              + ", ".join(f"{k}: {paper_fmt(v)}" for k, v in paper.POSITIONS.items()), ""]
        return L

    def figures(self, out: Path, cfg: ExperimentConfig, results: dict) -> list[str]:
        """``rx_count.png``: per room and task, Baseline's static, dynamic and where-the-person-matters
        SSIM (mean and seed std) against its training positions, Ours at its own positions plus
        the walk, and the nearest-neighbour floors; nothing when no job has finished."""
        from ...core import plots
        from ...data.split import ANTENNA_TEST_FRACTION

        own = cfg.data.positions - int(round(ANTENNA_TEST_FRACTION * cfg.data.positions))
        pairs = self._pairs(cfg)
        if not any(select(results, dataset=m.key, method="baseline") for m, _ in pairs):
            return []
        fig, axes = plots.subplots(1, len(pairs), figsize=(4.6 * len(pairs), 3.8), squeeze=False)
        for ax, (main, extra) in zip(axes[0], pairs):
            series = [(own, select(results, dataset=main.key, method="baseline"))] + [
                (n, select(results, dataset=extra.key, method="baseline", positions=n, eval_dataset=main.key))
                for n in sorted(cfg.rx_counts)]
            ro = select(results, dataset=main.key, method="ours")
            rb = series[0][1]
            for path, name, color in ((STAT, "static", "tab:blue"), (DYN, "dynamic", "tab:orange"),
                                      (AFF, "where the person matters", "tab:red")):
                pts = [(n, *mean_std_n(rs, path)[:2]) for n, rs in series if mean_std_n(rs, path)[2]]
                if pts:
                    x, y, e = zip(*pts)
                    ax.errorbar(x, y, yerr=e, marker="o", color=color, capsize=3, label=f"Baseline, {name}")
                mo, so, no = mean_std_n(ro, path)
                if no and path != STAT:
                    ax.errorbar([own], [mo], yerr=[so], marker="*", markersize=13, color=color, linestyle="none",
                                label=f"Ours ({own} + walk), {name}")
                    ax.axhline(mo, color=color, linestyle=":", alpha=0.6)
            for path, name in ((STAT_NN, "static"), (DYN_NN, "dynamic")):
                mn = mean(rb, path)
                if math.isfinite(mn):
                    ax.axhline(mn, color="grey", linestyle="--", alpha=0.5, linewidth=1)
                    ax.annotate(f"NN {name}", (own, mn), fontsize=7, color="grey", va="bottom")
            ax.set_xscale("log")
            ticks = [n for n, _ in series]
            ax.set_xticks(ticks, [str(n) for n in ticks])
            ax.minorticks_off()
            ax.set_title(f"{paper.ROOM_LABELS.get(main.scene, main.scene)}, moving {main.task.upper()}", fontsize=9)
            plots.label(ax, xlabel="Baseline's training positions", ylabel="test SSIM (mean over seeds)",
                        legend_fontsize=6)
        plots.save(fig, Path(out) / "rx_count.png")
        return ["![Static positions against one walk](rx_count.png)", ""]
