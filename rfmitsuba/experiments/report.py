"""The Markdown report of :func:`rfmitsuba.experiments.reproduce.reproduce`: the paper's tables (ours as
mean +- std over seeds beside the published figures), claims checked, speed against accuracy,
and where each method breaks.

Input: ``results`` = {"<dataset>/<job>": metrics of :func:`rfmitsuba.experiments.reproduce.reproduce_job`}.
Output: ``OUT/report.md`` and ``OUT/speed_accuracy.png`` (:mod:`rfmitsuba.experiments.curves`).
"""
from __future__ import annotations

import dataclasses
import json
import math
import platform
import time
from pathlib import Path

from ..core.atomic import write_text
from ..train.config import training_downsample
from .curves import speed_accuracy
from .methods import METHODS
from .paper_tables import TABLES, all_jobs
from .results import (
    BELOW_FLOORS,
    DYN,
    LABEL,
    Claims,
    fmt,
    format_below,
    mean,
    mean_std_n,
)
from .sizes import method_config


def _model_line(cfg) -> str:
    """What the training sizes of an experiment mean for its model family."""

    t = cfg.train
    if t.model == "coherent":
        return ("Coherent model (image sources of the room read out by Bartlett, `rfmitsuba.models.coherent`): "
                "training images 90x360, one source per image of each room, Stage 2 of kind "
                f"`{method_config(cfg.train, scene_known=cfg.source == 'sionna').coherent_person.kind}`")
    if t.model == "coherent_gaussians":
        m = method_config(cfg.train, scene_known=cfg.source == "sionna")
        d = training_downsample(m.stage1)
        return ("Coherent Gaussian field (`rfmitsuba.models.coherent_gaussians`: image sources of the room "
                "with ray-cast visibility where the room is known, else found by the data scan, plus scatterers, "
                f"read out by Bartlett): training images {90 // d}x{360 // d} (block means), validation at 90x360; "
                "Stage 2 the person field "
                f"(`coherent_gaussians_person`, {m.coherent_gaussians_person.num_points} body scatterers + blockage); "
                "End-to-End the joint field (`coherent_gaussians_joint`)")
    return (f"Splat model: training images {90 // t.downsample}x{360 // t.downsample}, {t.num_gaussians} initial "
            f"background Gaussians, {t.person_gaussians} person Gaussians")


def table_wall_times(cfg, results: dict) -> list[str]:
    """Markdown: per configured table, its jobs (with those they build on) and the sum of their
    wall times (training + evaluation, ``wall_s`` of each job's metrics); a job shared by
    tables counts in each, the total counts it once."""
    L = ["Wall time per table (each job's training + evaluation as it ran; a job shared by several tables "
         "counts in each, the total once; dataset generation not included):", "",
         "| table | jobs | done | wall time (min) |", "|---|---|---|---|"]
    everything: dict[str, float] = {}
    for key in cfg.tables:
        sub = dataclasses.replace(cfg, tables=[key])
        names = [f"{j.dataset.key}/{j.key}" for j in all_jobs(sub)]
        walls = {n: results[n]["wall_s"] for n in names if n in results and "wall_s" in results[n]}
        everything.update(walls)
        L.append(f"| {key} | {len(names)} | {len(walls)} | {sum(walls.values()) / 60:.1f} |")
    L += [f"| **all** | {len(all_jobs(cfg))} | {len(everything)} | {sum(everything.values()) / 60:.1f} |", ""]
    return L


#: one JSON line per reproduction run into the folder that reached its end
#: (:func:`rfmitsuba.experiments.reproduce.record_run`)
RUNS_FILE = "runs.jsonl"


def _runs_line(out: Path) -> str:
    """The wall times of every run into ``out`` (``runs.jsonl``, written by
    :func:`rfmitsuba.experiments.reproduce.record_run`; runs stopped early included and marked),
    where there was more than one."""
    f = Path(out) / RUNS_FILE
    runs = [json.loads(line) for line in f.read_text().splitlines() if line.strip()] if f.is_file() else []
    if len(runs) < 2:
        return ""
    walls = [float(r["wall_s"]) for r in runs]
    stopped = sum(bool(r.get("stopped")) for r in runs)
    return (f"; the folder was made by {len(runs)} runs"
            + (f" ({stopped} stopped early)" if stopped else " that reached their end") + ", "
            + " + ".join(f"{w:.0f} s ({r['jobs_run']} jobs" + (f", stopped: {r['stopped']}" if r.get("stopped") else "")
                         + ")" for w, r in zip(walls, runs))
            + f" = {sum(walls):.0f} s ({sum(walls) / 3600:.2f} h) of wall time")


def _dataset_sizes(cfg) -> str:
    """The run's datasets as the header states them: ``P antenna positions x (1 + W) states``
    per kind (the empty room and W walk positions; an empty-room dataset of the Rx-count table:
    its own positions x 1 state), several joined by "; "."""
    kinds = set()
    for job in all_jobs(cfg):
        d = job.dataset
        kinds.add((d.static_positions, 0) if d.static_positions else
                  (cfg.data.positions, d.walk_positions or cfg.data.person_positions))
    kinds = sorted(kinds or {(cfg.data.positions, cfg.data.person_positions)}, key=lambda k: (k[1] == 0, k))
    return "; ".join(f"{p} antenna positions x " + (f"(1 + {w}) states" if w else "1 state") for p, w in kinds)


def _ray_samples(cfg) -> str:
    """The ray samples per source of the configuration's Sionna datasets, as the header states them."""
    if cfg.source != "sionna":
        return ""
    if cfg.data.samples_per_src:
        return f", {cfg.data.samples_per_src} ray samples per source in every room"
    if cfg.data.samples_scale == 1.0:
        return ", each room's default ray samples per source"
    return f", {cfg.data.samples_scale:g} x each room's default ray samples per source"


def write_report(out: Path, cfg, results: dict, *, wall_s: float | None, jobs_total: int | None = None) -> Path:
    """Write ``out/report.md`` (+ ``speed_accuracy.png``): the header, each configured table's
    section (:data:`rfmitsuba.experiments.paper_tables.TABLES`), speed against accuracy, where
    methods break and the verdicts on the paper's claims; returns the report path.
    ``wall_s``: this run's wall time [s], or None for a report of the jobs finished so far
    (``reproduce --report-only``; ``jobs_total`` then names how many the configuration has)."""
    out = Path(out)
    L: list[str] = []
    claims = Claims()
    seeds = ", ".join(str(s) for s in cfg.seeds)
    try:
        load = " / ".join(f"{x:.2f}" for x in __import__("os").getloadavg())
    except OSError:
        load = "n/a"
    t = cfg.train
    L += ["# rfmitsuba reproduction of *One Walk is All You Need*", "",
          f"Size **{cfg.size}** (data source {cfg.source}: {_dataset_sizes(cfg)} per dataset"
          f"{_ray_samples(cfg)}), seeds {seeds}; every figure "
          "of ours is mean ± sample std over the seeds. Written "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; "
          + (f"this run took {wall_s:.0f} s wall time (jobs finished earlier and skipped are not included)"
             if wall_s is not None else
             f"from the {len(results)} of {jobs_total} jobs finished so far (`reproduce --report-only`; "
             "the others show as \"-\")")
          + _runs_line(out)
          + f" on {platform.machine()} with "
          f"{__import__('os').cpu_count()} cores, load average {load} at the end (the cores are shared).", "",
          "Training budgets (optimizer steps): Baseline = Stage 1 = "
          f"{t.stage1_iterations}; Stage 2 = {t.stage2_iterations}; Ours, End-to-End, Baseline (person), "
          f"Baseline (duplicated) and Continued baseline = {t.stage1_iterations + t.stage2_iterations} "
          f"(equal budgets; Ours and Continued go on from the Baseline of their seed: Stage 2, or "
          f"{t.stage2_iterations} more steps on the empty room at Stage 1's final learning rates). "
          f"{_model_line(cfg)}, {t.batch_views} views per step. Evaluation at full 90x360 by the metric "
          "protocol.", "",
          "Two evaluations: **dynamic** = unseen antenna x unseen person positions against the person-present "
          "ground truth (floors: nearest neighbour over antenna + person position, mean image); **static** = "
          "the background alone at unseen antenna positions against the empty room (floors over the antenna "
          "position). By construction Ours' static result equals its Stage 1 = Baseline (the background is "
          "frozen), so the paper's gains can only appear in the dynamic evaluation.", ""]

    for key in cfg.tables:
        L += TABLES[key].section(cfg, results, claims)
        L += TABLES[key].figures(out, cfg, results)

    # ---------------------------------------------------------------- speed
    L += ["## Speed against accuracy", "", "Every dataset's clean jobs (all training positions, no added noise):", ""]
    L += speed_accuracy(out / "speed_accuracy.png", speed_groups(results))
    L += ["Every job: training wall time (Ours and Continued include their Stage 1, the Baseline of the same "
          "seed), render time and dynamic test mean SSIM.", "",
          "| method | jobs | training wall time (s) | render time per PAS (ms, 90x360) | sources / Gaussians | "
          "dynamic mean |",
          "|---|---|---|---|---|---|"]
    for m in METHODS:
        rs = [r for r in results.values() if r["job"]["method"] == m]
        if rs:
            L.append(f"| {LABEL[m]} | {len(rs)} | {fmt(rs, 'train.train_time_s', 1)} | "
                     f"{fmt(rs, 'eval.render_ms_per_pas', 1)} | {fmt(rs, 'eval.num_gaussians', 0)} | {fmt(rs, DYN)} |")
    L.append("")
    L += table_wall_times(cfg, results)

    # ---------------------------------------------------------------- stability
    L += where_methods_break(results)

    # ---------------------------------------------------------------- claims
    L += ["## Paper claims on our data", "", "| claim | paper | ours | verdict |", "|---|---|---|---|"]
    L += claims.rows or ["| (no table run) | | | |"]
    L += ["", "Numbers of the paper are copied from its LaTeX tables (`rfmitsuba/paper.py`); ours come from "
          "`results.json` in this folder.", ""]
    return write_text(out / "report.md", "\n".join(L))


def where_methods_break(results: dict) -> list[str]:
    """The report's "Where methods break": every configuration (dataset, method, noise, positions,
    layout, walk) whose mean over seeds falls below the nearest-neighbour or IDW-3 floor of the same
    evaluation (:data:`~rfmitsuba.experiments.results.BELOW_FLOORS`; with training noise the floors
    of the same noisy training data), each with the floors it misses, then the largest
    seed-to-seed std per method; ``results`` {key: metrics with "job"}. Markdown lines."""
    L = ["## Where methods break (below the nearest-neighbour or IDW-3 floor)", "",
         "A configuration is listed when the mean over seeds of a method falls below the nearest-neighbour (NN) "
         "or the IDW-3 floor of the same evaluation, naming each floor it misses (with training noise: the floors "
         "looked up in the same noisy training data, where a job of that noise level recorded them); the largest "
         "seed-to-seed std per method is given too.", ""]
    groups: dict = {}
    noisy_floor: dict = {}   # (dataset, snr, positions, part, floor) -> floors on the noisy training data, per job
    for r in results.values():
        j = r["job"]
        key = (j["dataset"], j["method"], j["snr_db"], j["positions"], j.get("layout", "random"), j.get("walk_frames"))
        groups.setdefault(key, []).append(r)
        for part, (_, fps) in BELOW_FLOORS.items():
            for name, _, noisy in fps:
                v = mean([r], noisy)
                if j["snr_db"] != "none" and math.isfinite(v):
                    noisy_floor.setdefault((j["dataset"], j["snr_db"], j["positions"], part, name), []).append(v)
    broken, below_nn, n_runs = [], 0, 0   # n_runs: results with a model mean and a clean NN floor
    for (ds, m, snr, n, layout, walk), rs in sorted(groups.items(), key=lambda kv: str(kv[0])):
        for part, (mp, fps) in BELOW_FLOORS.items():
            a = mean(rs, mp)
            under, noisy = [], False
            for name, fp, _ in fps:
                f = mean(rs, fp)
                n_runs += name == "NN" and math.isfinite(a) and math.isfinite(f)
                if (ds, snr, n, part, name) in noisy_floor:
                    vs = noisy_floor[(ds, snr, n, part, name)]
                    f, noisy = sum(vs) / len(vs), True
                if math.isfinite(a) and math.isfinite(f) and a < f:
                    under.append((name, f))
            if under:
                below_nn += any(name == "NN" for name, _ in under)
                cond = (ds + ("" if snr == "none" else f", SNR {snr:g} dB")
                        + (f", {n} positions" + (f" ({layout})" if layout != "random" else "") if n else "")
                        + ("" if walk is None else f", walk {walk}"))
                broken.append(f"- {LABEL[m]}, {cond}: {part} {format_below(a, under)}"
                              + (" (floors on the same noisy training data)" if noisy else ""))
    L += broken or ["- none: every method beats the nearest-neighbour and IDW-3 floors everywhere"]
    if n_runs and below_nn > n_runs / 2:
        L += ["", f"**{below_nn} of {n_runs} results are below the nearest-neighbour floor: at this size "
              "the report checks the pipeline, not the methods.** The verdicts below are about this size only."]
    L.append("")
    for m in METHODS:
        sds = [mean_std_n(rs, DYN)[1] for (ds, mm, *_), rs in groups.items() if mm == m and len(rs) > 1]
        if sds:
            L.append(f"- {LABEL[m]}: largest std over seeds of the dynamic mean {max(sds):.3f}")
    L.append("")
    return L


def speed_groups(results: dict) -> dict[str, list[tuple[str, int, dict]]]:
    """The jobs of the speed-accuracy curves: per dataset, those on clean data with every training
    position, as (method, seed, metrics)."""
    groups: dict = {}
    for r in results.values():
        j = r["job"]
        if j["snr_db"] == "none" and not j["positions"]:
            groups.setdefault(j["dataset"], []).append((j["method"], j["seed"], r))
    return groups
