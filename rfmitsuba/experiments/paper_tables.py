"""The paper's tables, one object each: its jobs, its report section and its claims.

A :class:`Table` says which jobs (:class:`rfmitsuba.experiments.job.Job`) it needs for one seed
(:meth:`Table.jobs`) and writes its Markdown section from the finished jobs' results, adding its
verdicts on the paper's claims (:meth:`Table.section`). :data:`TABLES` holds them by the names
of :data:`rfmitsuba.experiments.sizes.TABLES`; ``reproduce`` runs the union of their jobs and
``report`` writes their sections in order. A new table is one class here.
"""
from __future__ import annotations

import math
from pathlib import Path

from ..eval.breakdown import DISTANCES
from ..eval.dynamic_static import AFFECTED_SSIM, FIT_POSITIONS
from . import paper
from .job import Job
from .results import (
    AFF,
    AFF_EMPTY,
    AFF_NN,
    BELOW_FLOORS,
    DYN,
    DYN_IDW,
    DYN_IDW_NOISY,
    DYN_MED,
    DYN_MI,
    DYN_NN,
    DYN_NN_NOISY,
    LABEL,
    STAT,
    STAT_FIT,
    STAT_IDW,
    STAT_MED,
    STAT_MI,
    STAT_NN,
    Claims,
    fmt,
    format_below,
    mean,
    mean_std_n,
    paper_fmt,
    select,
    value,
)
from .sizes import TABLES as TABLE_NAMES
from .sizes import DatasetSpec, ExperimentConfig
from .truth import load_summary, truth_folder


def _ref(cfg: ExperimentConfig) -> DatasetSpec:
    """The reference dataset of the ablations: the first room and task."""
    return DatasetSpec(cfg.rooms[0], cfg.tasks[0])


class Table:
    """One table of the paper: ``key`` (its name in ``ExperimentConfig.tables``), its jobs per seed
    and its report section."""

    key = ""

    def jobs(self, cfg: ExperimentConfig, seed: int) -> list[Job]:
        """The jobs this table needs for training seed ``seed``."""
        raise NotImplementedError

    def section(self, cfg: ExperimentConfig, results: dict, claims: Claims) -> list[str]:
        """Markdown lines of this table from ``results`` (jobs not yet run show as "-"); adds the
        verdicts of its claims to ``claims``."""
        raise NotImplementedError

    def figures(self, out: Path, cfg: ExperimentConfig, results: dict) -> list[str]:
        """Draw this table's figures into folder ``out``; Markdown lines that show them (none by default)."""
        return []


class MainTable(Table):
    """Every room x task: Baseline, End-to-End and Ours (the paper's columns), then the
    ablations' Continued, Duplicated and Baseline (person) in every cell too, with the floors
    (paper Table `tab:generalization_combined_concise`)."""

    key = "main"
    #: the ablations' methods, trained for Ours' steps: judged against Ours in every cell
    equal_steps = ("continued", "duplicated", "baseline_person")
    methods = ("baseline", "end_to_end", "ours") + equal_steps

    def jobs(self, cfg: ExperimentConfig, seed: int) -> list[Job]:
        return [Job(DatasetSpec(r, k), m, seed) for r in cfg.rooms for k in cfg.tasks for m in self.methods]

    def section(self, cfg: ExperimentConfig, results: dict, claims: Claims) -> list[str]:
        L: list[str] = []
        L += ["## Main table (paper Table `tab:generalization_combined_concise`)", "",
              "*Where the person matters* = the dynamic test PAS whose SSIM against the empty room's PAS at the "
              f"same antenna is below {AFFECTED_SSIM:g} (`methods.evaluate`, part \"affected\"); its floor row adds the "
              "empty room's own PAS as a prediction, what a perfect background model reaches there.", "",
              "| scene | task | method | dynamic mean | dynamic median | static mean | where the person matters | "
              "paper mean / median |",
              "|---|---|---|---|---|---|---|---|"]
        n_ob, n_oe, n_tot = 0, 0, 0
        equal = {(m, part): [0, 0] for m in self.equal_steps for part in (DYN, AFF)}
        for r in cfg.rooms:
            for k in cfg.tasks:
                ds = DatasetSpec(r, k).key
                for m in self.methods:
                    rs = select(results, dataset=ds, method=m)
                    L.append(f"| {paper.ROOM_LABELS.get(r, r)} | moving {k.upper()} | {LABEL[m]} | {fmt(rs, DYN)} | "
                             f"{fmt(rs, DYN_MED)} | {fmt(rs, STAT)} | {fmt(rs, AFF)} | {paper_fmt(paper.MAIN.get((r, k, m)))} |")
                rb = select(results, dataset=ds, method="baseline")
                L.append(f"| | | *nearest neighbour / mean image (empty room)* | {fmt(rb, DYN_NN)} / "
                         f"{fmt(rb, DYN_MI)} | | {fmt(rb, STAT_NN)} / {fmt(rb, STAT_MI)} | {fmt(rb, AFF_NN)} "
                         f"({fmt(rb, AFF_EMPTY)}) | |")
                ro, re_ = select(results, dataset=ds, method="ours"), select(results, dataset=ds, method="end_to_end")
                o, b, e = mean(ro, DYN), mean(rb, DYN), mean(re_, DYN)
                if all(math.isfinite(x) for x in (o, b, e)):
                    n_tot += 1
                    n_ob += o > b
                    n_oe += o > e
                # the equal-budget comparisons: Ours' 4500 steps against the ablations' 4500
                for m in self.equal_steps:
                    rm = select(results, dataset=ds, method=m)
                    for part in (DYN, AFF):
                        x, y = mean(ro, part), mean(rm, part)
                        if math.isfinite(x) and math.isfinite(y):
                            equal[(m, part)][0] += x > y
                            equal[(m, part)][1] += 1
                where = f"{paper.ROOM_LABELS.get(r, r)}, moving {k.upper()}"
                pb, pe = paper.MAIN.get((r, k, "baseline")), paper.MAIN.get((r, k, "end_to_end"))
                po = paper.MAIN.get((r, k, "ours"))
                claims.paired(f"Ours beats Baseline ({where}, dynamic)",
                              f"{po[0]:.3f} vs {pb[0]:.3f}" if po and pb else "-", ro, rb, DYN, names=("Ours", "Baseline"))
                claims.paired(f"Ours beats Baseline where the person matters ({where})", "-", ro, rb, AFF,
                              names=("Ours", "Baseline"))
                claims.paired(f"Ours beats End-to-End ({where}, dynamic)",
                              f"{po[0]:.3f} vs {pe[0]:.3f}" if po and pe else "-", ro, re_, DYN,
                              names=("Ours", "End-to-End"))
        L.append("")
        claims.add("Ours beats Baseline (every scene and task)", "Table main: +0.03 to +0.10",
                   f"{n_ob} of {n_tot} scene/task pairs (dynamic mean)", (n_ob == n_tot) if n_tot else None)
        claims.add("Ours beats End-to-End (every scene and task)", "Table main",
                   f"{n_oe} of {n_tot} pairs (dynamic mean)", (n_oe == n_tot) if n_tot else None)
        for (m, part), (wins, n) in equal.items():
            if n:
                where = "dynamic mean" if part == DYN else "mean where the person matters"
                claims.add(f"Ours beats {LABEL[m]} with the same steps (every scene and task, {where})", "-",
                           f"{wins} of {n} scene/task pairs", wins == n)
        return L

    def figures(self, out: Path, cfg: ExperimentConfig, results: dict) -> list[str]:
        return truth_band(out, cfg, results)


def truth_band(out: Path, cfg: ExperimentConfig, results: dict) -> list[str]:
    """Markdown lines placing the main table's static figures against the ground truth's own error
    bar: the truth checks of ``reproduce`` in ``out`` (:func:`rfmitsuba.experiments.truth.truth_folder`);
    none where no check has run."""
    found = {(r, k): load_summary(truth_folder(out, r, k)) for r in cfg.rooms for k in cfg.tasks}
    found = {rk: s for rk, s in found.items() if s is not None}
    if not found:
        return []
    rows, spreads = [], []
    for (r, k), s in found.items():
        band, noise = s["stats"]["ssim"], (s.get("noise") or {}).get("stats", {}).get("ssim")
        ds = DatasetSpec(r, k).key
        static = {m: mean(select(results, dataset=ds, method=m), STAT) for m in ("baseline", "end_to_end", "ours")}
        done = {m: v for m, v in static.items() if math.isfinite(v)}
        if len(done) > 1:
            spreads.append(max(done.values()) - min(done.values()))
        above = sum(v > band["mean"] for v in done.values())
        rows.append(f"| {paper.ROOM_LABELS.get(r, r)} | moving {k.upper()} | {s['count']} | "
                    f"{band['mean']:.3f} / {band['median']:.3f} / {band['p10']:.3f} | "
                    + (f"{noise['mean']:.3f}" if noise else "-") + " | "
                    + " / ".join(f"{static[m]:.3f}" if m in done else "-" for m in static)
                    + f" | {above} of {len(done)} | [table]({(truth_folder(out, r, k) / 'table.md').relative_to(out).as_posix()}) |")
    samples = (next(iter(found.values())).get("solver") or {}).get("samples_per_src")
    L = ["### The ground truth's own error bar", "",
         "Every dataset's truth is Sionna's synthetic array: one trace per array position, each element's "
         "phase by the plane-wave rule. The truth check (`rfmitsuba.experiments.truth`) traces positions of "
         "the empty room again with each of the 16 elements as its own antenna"
         + (f", at the datasets' {samples:.0f} ray samples per source" if samples else "")
         + "; the band is the PAS SSIM between the two truths (metric protocol), the ray-sampling share "
         "the exact truth against itself traced with the next solver seed.", "",
         "| scene | task | PAS | synthetic vs exact: mean / median / 10th pct | ray-sampling share (mean) | "
         "static mean: Baseline / End-to-End / Ours | above the band's mean | |",
         "|---|---|---|---|---|---|---|---|"] + rows + [""]
    if spreads:
        gap = 1 - max(s["stats"]["ssim"]["mean"] for s in found.values())
        L += ["A static figure above the band's mean agrees with the synthetic truth better than that truth "
              "agrees with tracing every element: it measures the dataset's approximation as much as the room's "
              f"field. Within a scene and task the methods' static means differ by at most {max(spreads):.3f}; "
              f"every band's mean lies at least {gap:.3f} below 1.", ""]
    return L


class TwoStageTable(Table):
    """Two-stage ablation: Baseline, End-to-End, Continued, Ours on the first room and task
    (paper Table `tab:ablation_strategy`)."""

    key = "two_stage"
    methods = ("baseline", "end_to_end", "continued", "ours")

    def jobs(self, cfg: ExperimentConfig, seed: int) -> list[Job]:
        return [Job(_ref(cfg), m, seed) for m in self.methods]

    def section(self, cfg: ExperimentConfig, results: dict, claims: Claims) -> list[str]:
        room, task = cfg.rooms[0], cfg.tasks[0]
        ref = _ref(cfg).key
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


class PerturbationTable(Table):
    """Role of perturbation data: Baseline, Duplicated, Baseline (person), Ours (paper Table `tab:ablation_info`)."""

    key = "perturbation"
    methods = ("baseline", "duplicated", "baseline_person", "ours")

    def jobs(self, cfg: ExperimentConfig, seed: int) -> list[Job]:
        return [Job(_ref(cfg), m, seed) for m in self.methods]

    def section(self, cfg: ExperimentConfig, results: dict, claims: Claims) -> list[str]:
        room, task = cfg.rooms[0], cfg.tasks[0]
        ref = _ref(cfg).key
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
        from ..core import plots

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


class PositionsTable(Table):
    """Number of training positions: Baseline and Ours at each count (paper Table `tab:motivation`)."""

    key = "positions"

    def jobs(self, cfg: ExperimentConfig, seed: int) -> list[Job]:
        return [Job(_ref(cfg), m, seed, positions=n) for n in list(cfg.position_counts) + [0]
                for m in ("baseline", "ours")]

    def section(self, cfg: ExperimentConfig, results: dict, claims: Claims) -> list[str]:
        room, task = cfg.rooms[0], cfg.tasks[0]
        ref = _ref(cfg).key
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


class NoiseTable(Table):
    """Measurement noise on the training channels at each SNR (not in the paper)."""

    key = "noise"

    def jobs(self, cfg: ExperimentConfig, seed: int) -> list[Job]:
        return [Job(_ref(cfg), m, seed, snr_db=snr) for snr in [None] + list(cfg.snr_db)
                for m in ("baseline", "end_to_end", "ours")]

    def section(self, cfg: ExperimentConfig, results: dict, claims: Claims) -> list[str]:
        room, task = cfg.rooms[0], cfg.tasks[0]
        ref = _ref(cfg).key
        L: list[str] = []
        L += [f"## Measurement noise on the training data ({room}, moving {task.upper()}; not in the paper)", "",
              "Complex white noise added to the training channels at the given SNR (PAS recomputed); test data clean. "
              "The floors are looked up in the same training data the models saw: noisy at that SNR (the noise seed "
              "is the job's seed), against the clean test PAS.", "",
              "| SNR (dB) | Baseline dynamic | End-to-End dynamic | Ours dynamic | dynamic NN floor | dynamic IDW-3 floor |",
              "|---|---|---|---|---|---|"]
        for snr in [None] + list(cfg.snr_db):
            row = [fmt(select(results, dataset=ref, method=m, snr=snr), DYN) for m in ("baseline", "end_to_end", "ours")]
            base = select(results, dataset=ref, method="baseline", snr=snr)
            noisy = snr is not None
            nn = fmt(base, DYN_NN_NOISY if noisy else DYN_NN)
            idw = fmt(base, DYN_IDW_NOISY if noisy else DYN_IDW)
            L.append(f"| {'clean' if snr is None else f'{snr:g}'} | " + " | ".join(row) + f" | {nn} | {idw} |")
        L.append("")
        return L



#: every table by name, in report order
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
        return [Job(_ref(cfg), m, seed) for m in self.methods]

    def section(self, cfg: ExperimentConfig, results: dict, claims: Claims) -> list[str]:
        room, task = cfg.rooms[0], cfg.tasks[0]
        ref = _ref(cfg).key
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


def static_positions_for(train_positions: int) -> int:
    """Antenna positions of a dataset whose training split (80%, docs/conventions.md) holds at
    least ``train_positions``."""
    from ..data.split import ANTENNA_TEST_FRACTION

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
        from ..data.split import ANTENNA_TEST_FRACTION

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
        from ..core import plots
        from ..data.split import ANTENNA_TEST_FRACTION

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
        from .break_even import worth_over_seeds

        return worth_over_seeds(self.counts(cfg), self.curves(cfg, results, ds, "baseline", 0),
                                self.curves(cfg, results, ds, self.static_method(cfg), walk), at=at)

    def _over_continued(self, cfg: ExperimentConfig, results: dict, ds: DatasetSpec) -> list[str]:
        """The grid of the walk's static gain over Continued (the same positions, trained longer
        without the walk), paired over seeds, per static positions and walk length: what the walk
        adds beyond more steps. Empty where Continued has not run."""
        from .results import format_effect, paired_verdict

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
        from .break_even import format_worth
        from .results import format_effect, paired_verdict

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
        from ..core import plots

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


def plots_colours(n: int) -> list:
    """``n`` colours from light to dark, the longest walk darkest."""
    from matplotlib import colormaps

    cmap = colormaps["viridis"]
    return [cmap(0.85 - 0.7 * i / max(n - 1, 1)) for i in range(n)]


TABLES: dict[str, Table] = {t.key: t for t in (MainTable(), TwoStageTable(), PerturbationTable(), MaterialTable(),
                                                LargeRoomTable(), PositionsTable(), NoiseTable(), RxCountTable(),
                                                ThirdStageTable(), DataScarceTable())}
assert tuple(TABLES) == tuple(TABLE_NAMES), "paper_tables.TABLES and sizes.TABLES must name the same tables"


def table_jobs(cfg: ExperimentConfig) -> dict[str, list[Job]]:
    """The jobs of every configured table (a job may serve several tables)."""
    return {t: [j for seed in cfg.seeds for j in TABLES[t].jobs(cfg, seed)] for t in cfg.tables}


def all_jobs(cfg: ExperimentConfig) -> list[Job]:
    """Every job of the configured tables once, each after the jobs it builds on (Ours after its
    Baseline, Stage 3 after its Ours), grouped by training dataset (datasets in the order the
    tables first name them). A job reads gigabytes of its dataset (a walk of 35 states x 900
    positions is 4 GB); one dataset's jobs in a row find it in the page cache, where jobs
    taking turns between six such datasets read them from disk again each time."""
    seen: dict[str, Job] = {}
    for jobs in table_jobs(cfg).values():
        for j in jobs:
            chain = [j]
            while chain[-1].prior_job() is not None:
                chain.append(chain[-1].prior_job())
            for b in reversed(chain):
                seen.setdefault(f"{b.dataset.key}/{b.key}", b)
    order = {k: i for i, k in enumerate(dict.fromkeys(j.dataset.key for j in seen.values()))}
    return sorted(seen.values(), key=lambda j: order[j.dataset.key])  # stable: priors stay first
