"""The data-scarce table: where one walk pays, static positions on a coarse grid against walks."""
from __future__ import annotations

import math
from pathlib import Path

from .. import paper
from ..job import Job
from ..results import (
    AFF,
    AFF_NN,
    BELOW_FLOORS,
    DYN,
    LABEL,
    STAT,
    STAT_IDW,
    STAT_NN,
    Claims,
    fmt,
    format_below,
    mean,
    mean_std_n,
    select,
    value,
)
from ..sizes import DatasetSpec, ExperimentConfig
from .base import Table, plots_colours


class DataScarceTable(Table):
    """Where one walk pays: static training positions laid out on a coarse grid over the free
    floor (``cfg.scarce_positions``) against walks of ``cfg.walk_lengths`` positions (the first N
    of one long walk at its own pace), Baseline and Continued without the walk, Ours, Ours +
    Stage 3 and Baseline (person) with it; the first two rooms, every task. Every cell is tested
    on the same positions: the long-walk dataset's test antennas, and its test walk positions
    spread over the whole walk. The walk can only change the static scene through Stage 3
    (coherent Gaussian family; with another family Baseline (person) stands in)."""

    key = "data_scarce"
    static_methods = ("baseline", "continued")

    @staticmethod
    def walk_methods(cfg: ExperimentConfig) -> tuple[str, ...]:
        """The methods trained with the walk (Stage 3 in the coherent Gaussian family only)."""
        both = cfg.train.model == "coherent_gaussians"
        return ("ours", "refined", "baseline_person") if both else ("ours", "baseline_person")

    @classmethod
    def static_method(cls, cfg: ExperimentConfig) -> str:
        """The method whose static scene the walk changes: Stage 3, else Baseline (person)."""
        return "refined" if "refined" in cls.walk_methods(cfg) else "baseline_person"

    @staticmethod
    def datasets(cfg: ExperimentConfig) -> list[DatasetSpec]:
        """One long-walk dataset per room (the first two) and task."""
        return [DatasetSpec(r, k, walk_positions=max(cfg.walk_lengths)) for r in cfg.rooms[:2] for k in cfg.tasks]

    @staticmethod
    def counts(cfg: ExperimentConfig) -> list[int]:
        return sorted(set(cfg.scarce_positions))

    @staticmethod
    def walks(cfg: ExperimentConfig) -> list[int]:
        """The walk lengths above 0, ascending."""
        return sorted({w for w in cfg.walk_lengths if w > 0})

    @classmethod
    def one_walk(cls, cfg: ExperimentConfig) -> int:
        """The walk the break-even is read for: the size's walk (35 positions at the full size)
        where it is one of the walk lengths, else the shortest."""
        walks = cls.walks(cfg)
        return cfg.data.person_positions if cfg.data.person_positions in walks else walks[0]

    def jobs(self, cfg: ExperimentConfig, seed: int) -> list[Job]:
        out = []
        for ds in self.datasets(cfg):
            for n in self.counts(cfg):
                out += [Job(ds, m, seed, positions=n, layout="grid", walk_frames=0) for m in self.static_methods]
                out += [Job(ds, m, seed, positions=n, layout="grid", walk_frames=w)
                        for w in self.walks(cfg) for m in self.walk_methods(cfg)]
        return out

    @staticmethod
    def _cell(results: dict, ds: DatasetSpec, method: str, n: int, walk: int) -> list[dict]:
        return select(results, dataset=ds.key, method=method, positions=n, layout="grid", walk_frames=walk)

    def curves(self, cfg: ExperimentConfig, results: dict, ds: DatasetSpec, method: str, walk: int) -> dict:
        """Seed -> static mean SSIM [len(counts)] of ``method`` at walk length ``walk`` (NaN where
        a job has not run)."""
        counts = self.counts(cfg)
        out: dict = {}
        for i, n in enumerate(counts):
            for r in self._cell(results, ds, method, n, walk):
                v = value(r, STAT)
                out.setdefault(r["job"]["seed"], [math.nan] * len(counts))[i] = math.nan if v is None else float(v)
        return out

    def worth(self, cfg: ExperimentConfig, results: dict, ds: DatasetSpec, *, at: int, walk: int) -> dict:
        """How many static positions the walk of ``walk`` positions is worth at ``at`` static
        positions (:func:`rfmitsuba.experiments.break_even.worth_over_seeds`), Baseline's static
        curve against the walk's (:meth:`static_method`)."""
        from ..break_even import worth_over_seeds

        return worth_over_seeds(self.counts(cfg), self.curves(cfg, results, ds, "baseline", 0),
                                self.curves(cfg, results, ds, self.static_method(cfg), walk), at=at)

    def _over_continued(self, cfg: ExperimentConfig, results: dict, ds: DatasetSpec) -> list[str]:
        """The grid of the walk's static gain over Continued (the same positions, trained longer
        without the walk), paired over seeds, per static positions and walk length: what the walk
        adds beyond more steps. Empty where Continued has not run."""
        from ..results import format_effect, paired_verdict

        sm, walks = self.static_method(cfg), self.walks(cfg)
        rows, seen = [], False
        for n in self.counts(cfg):
            cont = self._cell(results, ds, "continued", n, 0)
            cells = []
            for w in walks:
                v = paired_verdict(self._cell(results, ds, sm, n, w), cont, STAT)
                if v is None:
                    cells.append("-")
                    continue
                seen = True
                text = format_effect(v)
                cells.append(f"**{text}**" if v["holds"] is True else text)
            rows.append(f"| {n} | " + " | ".join(cells) + " |")
        if not seen:
            return []
        return [f"Static gain of {LABEL[sm]} over Continued (the Baseline trained {cfg.train.stage2_iterations} "
                "steps longer on the same positions, without the walk), mean ± std of the per-seed differences; "
                "**bold** where it holds by the paired rule. This is what the walk adds beyond more steps:", "",
                "| static positions | " + " | ".join(f"walk {w}" for w in walks) + " |",
                "|---|" + "---|" * len(walks), *rows, ""]

    def section(self, cfg: ExperimentConfig, results: dict, claims: Claims) -> list[str]:
        from ..break_even import format_worth
        from ..results import format_effect, paired_verdict

        counts, walks, one = self.counts(cfg), self.walks(cfg), self.one_walk(cfg)
        lead, sm = counts[0], self.static_method(cfg)
        walk_ms = self.walk_methods(cfg)
        L = ["## Where one walk pays: scarce static data and the walk's length", "",
             f"Static training positions: {', '.join(map(str, counts))}, each a coarse grid over the free floor "
             "(`rfmitsuba.data.layout.grid_layout`: the largest square cells that leave that many cells holding a "
             "training position, the position nearest each cell's centre; the same for every seed and method). "
             f"Walks: the first {', '.join(map(str, walks))} positions of one walk of {max(walks)} positions at 35 "
             "positions a minute, of which the walk positions of the test split are never trained on; "
             f"{'0 = no walk (Baseline, Continued)' if 0 in cfg.walk_lengths else ''}. Every cell is tested on the "
             "same positions: the dataset's test antenna positions and, for the dynamic figures, its test walk "
             "positions spread over the whole walk. The floors look up the cell's own training samples "
             "(no walk: no dynamic floor). Static = the background alone on the empty room; Ours' equals its "
             f"Baseline's (frozen); the walk changes it only through {LABEL[sm]}.", ""]
        if sm != "refined":
            L += [f"Stage 3 needs the coherent Gaussian family; this experiment trains {cfg.train.model!r}, so "
                  "Baseline (person) carries the walk's static figures.", ""]
        never, cells = True, 0
        verdicts = []
        for ds in self.datasets(cfg):
            room, task = paper.ROOM_LABELS.get(ds.scene, ds.scene), f"moving {ds.task.upper()}"
            where = f"{room}, {task}"
            base = {n: self._cell(results, ds, "baseline", n, 0) for n in counts}
            # the summary grid: static mean of the walk's method per count and walk length
            L += [f"### {where}", "", f"Static mean ({LABEL[sm]}; walk 0: Baseline) by static positions and walk "
                  "length; **bold** where it beats the Baseline of the same positions by the paired rule:", "",
                  "| static positions | " + " | ".join(f"walk {w}" for w in [0] + walks) + " |",
                  "|---|" + "---|" * (1 + len(walks))]
            for n in counts:
                row = [fmt(base[n], STAT)]
                for w in walks:
                    rs = self._cell(results, ds, sm, n, w)
                    v = paired_verdict(rs, base[n], STAT)
                    if v is not None:
                        cells += 1
                        never = never and v["holds"] is not True
                    row.append(f"**{fmt(rs, STAT)}**" if v is not None and v["holds"] is True else fmt(rs, STAT))
                L.append(f"| {n} | " + " | ".join(row) + " |")
            L.append("")
            L += self._over_continued(cfg, results, ds)
            worth = {n: self.worth(cfg, results, ds, at=n, walk=one) for n in counts[:-1]}
            L += [f"Static positions one {one}-position walk is worth, read off the curves (Baseline's static curve "
                  f"reaches {LABEL[sm]}'s score at n + worth positions, linear in log positions; per seed, then "
                  "mean ± std):", "", "| static positions n | worth (positions) |", "|---|---|"]
            L += [f"| {n} | {format_worth(w)} |" for n, w in worth.items()] + [""]
            # the full table
            L += ["| static positions | walk | method | static mean | dynamic mean | where the person matters | "
                  "training s |", "|---|---|---|---|---|---|---|"]
            for n in counts:
                for w in [0] + walks:
                    for m in (self.static_methods if w == 0 else walk_ms):
                        rs = self._cell(results, ds, m, n, w)
                        L.append(f"| {n} | {w} | {LABEL[m]} | {fmt(rs, STAT)} | {fmt(rs, DYN)} | {fmt(rs, AFF)} | "
                                 f"{fmt(rs, 'train.train_time_s', 1)} |")
                    ref = self._cell(results, ds, "baseline" if w == 0 else "ours", n, w)
                    floors = lambda part: " / ".join(fmt(ref, f"eval.{part}.{f}.mean").split(" ±")[0]
                                                     for f in ("nearest_neighbour", "idw3", "mean_image"))
                    L.append(f"| | | *floors: NN / IDW-3 / mean image* | {floors('static')} | {floors('dynamic')} | "
                             f"{fmt(ref, AFF_NN).split(' ±')[0]} | |")
            L.append("")
            below: dict = {}      # (method, walk, part) -> ["positions (model < floor, ...)"]
            for n in counts:
                for w in [0] + walks:
                    for m in (self.static_methods if w == 0 else walk_ms):
                        rs = self._cell(results, ds, m, n, w)
                        for part, (p, fps) in BELOW_FLOORS.items():
                            a = mean(rs, p)
                            under = [(name, f) for name, fp, _ in fps for f in [mean(rs, fp)]
                                     if math.isfinite(a) and math.isfinite(f) and a < f]
                            if under:
                                below.setdefault((m, w, part), []).append(f"{n} ({format_below(a, under)})")
            L += ["Below a floor of the same training samples, nearest neighbour (NN) or IDW-3 (static positions, "
                  "model < floors):" + ("" if below else " none."), ""]
            L += [f"- {LABEL[m]}, walk {w}, {part}: " + ", ".join(v) for (m, w, part), v in below.items()]
            L += [""] if below else []
            rl = self._cell(results, ds, sm, lead, one)
            claim = f"One {one}-position walk improves the static scene at {lead} static positions ({where})"
            claims.paired(claim, "abstract", rl, base[lead], STAT, names=(LABEL[sm], "Baseline"))
            claims.paired(f"... and beats training longer on the {lead} positions (Continued; {where})", "-", rl,
                          self._cell(results, ds, "continued", lead, 0), STAT, names=(LABEL[sm], "Continued"))
            said = {True: "**holds**", False: "**fails**", "unclear": "**unclear**"}
            cells_ = []
            for other in (base[lead], self._cell(results, ds, "continued", lead, 0)):
                v = paired_verdict(rl, other, STAT)
                cells_ += ["-", "n/a (not run)"] if v is None else [format_effect(v),
                                                                    said[v["holds"]]]
            verdicts.append(f"| {room} | {task} | {format_worth(worth[lead]) if lead in worth else '-'} | "
                            + " | ".join(cells_) + " |")
        L += [f"### Verdicts: one {one}-position walk at {lead} static positions", "",
              f"Paired over seeds ({LABEL[sm]} against the Baseline, and against Continued, of the same {lead} "
              "positions, static mean): holds when every seed gains and the mean gain exceeds its spread, fails when "
              "no seed gains or the mean is below minus the spread, else unclear. Continued has "
              f"{cfg.train.stage2_iterations} steps fewer than {LABEL[sm]} and none on the walk.", "",
              "| scene | task | worth (static positions) | static gain over Baseline | verdict | "
              "gain over Continued (trained longer, no walk) | verdict |", "|---|---|---|---|---|---|---|", *verdicts,
              ""]
        if cells and never:
            L += [f"**The walk never improves the static scene.** In none of the {cells} cells (static positions x "
                  f"walk length, every room and task) does {LABEL[sm]} beat the Baseline of the same positions on "
                  "every seed by more than the seed spread: its static curves lie on the Baseline's (figure below).",
                  ""]
        return L

    def figures(self, out: Path, cfg: ExperimentConfig, results: dict) -> list[str]:
        """``data_scarce.png``: per room and task the static SSIM (mean and seed std) over the static
        positions, one curve per walk length (walk 0: Baseline; else :meth:`static_method`),
        Continued and the nearest-neighbour and IDW-3 floors beside them; nothing when no job has finished."""
        from ...core import plots

        counts, walks, sm = self.counts(cfg), self.walks(cfg), self.static_method(cfg)
        dss = self.datasets(cfg)
        if not any(self._cell(results, ds, "baseline", n, 0) for ds in dss for n in counts):
            return []
        cols = min(len(dss), 2)
        rows = -(-len(dss) // cols)
        fig, axes = plots.subplots(rows, cols, figsize=(5.2 * cols, 3.9 * rows), squeeze=False)
        colours = plots_colours(len(walks))
        for ax, ds in zip(axes.ravel(), dss):
            series = [("Baseline (no walk)", "baseline", 0, "black", "-")]
            series += [(f"{LABEL[sm]}, walk {w}", sm, w, c, "-") for w, c in zip(walks, colours)]
            series += [("Continued (no walk)", "continued", 0, "grey", "--")]
            for name, m, w, colour, style in series:
                pts = [(n, *mean_std_n(rs, STAT)[:2]) for n in counts
                       for rs in [self._cell(results, ds, m, n, w)] if mean_std_n(rs, STAT)[2]]
                if pts:
                    x, y, e = zip(*pts)
                    ax.errorbar(x, y, yerr=e, marker="o", markersize=4, capsize=3, color=colour, linestyle=style,
                                label=name)
            base = {n: self._cell(results, ds, "baseline", n, 0) for n in counts}
            for path, style, name in ((STAT_NN, ":", "nearest neighbour"), (STAT_IDW, "-.", "IDW-3")):
                floor = [(n, mean(base[n], path)) for n in counts]
                floor = [(n, v) for n, v in floor if math.isfinite(v)]
                if floor:
                    ax.plot(*zip(*floor), style, color="grey", label=name)
            ax.set_xscale("log")
            ax.set_xticks(counts, [str(n) for n in counts])
            ax.minorticks_off()
            ax.set_title(f"{paper.ROOM_LABELS.get(ds.scene, ds.scene)}, moving {ds.task.upper()}", fontsize=9)
            plots.label(ax, xlabel="static training positions (grid layout)", ylabel="static test SSIM",
                        legend_fontsize=6 if ax.get_legend_handles_labels()[0] else None)
        for ax in axes.ravel()[len(dss):]:
            ax.set_visible(False)
        plots.save(fig, Path(out) / "data_scarce.png")
        return ["![Static SSIM over static positions, one curve per walk length](data_scarce.png)", ""]
