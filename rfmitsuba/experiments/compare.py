"""Compare methods on one dataset of your own: train each over seeds, evaluate, tabulate.

:func:`compare` is what ``rfmitsuba compare DATASET --out DIR`` runs. For every seed it trains
the requested methods of :mod:`rfmitsuba.experiments.methods` (Ours reuses that seed's Baseline as its
Stage 1, so Baseline and Ours share one background), evaluates each by both protocols
(dynamic: unseen antenna x unseen person positions; static: the background alone) with the
nearest-neighbour, IDW-3 and mean-image floors, and writes

    DIR/compare.toml        the configuration (a folder of other training sizes is refused; seeds
                            and methods may be added later: their jobs are new folders)
    DIR/seed<S>/<method>/   each job: runs, metrics.json, DONE
    DIR/results.json        every job's metrics
    DIR/report.md           mean +- std over seeds, floors, training and render time
    DIR/speed_accuracy.png  validation SSIM against cumulative training wall time, sampled during
                            training, every method (rfmitsuba.experiments.curves)

Jobs with a DONE marker are not run again, so a killed comparison resumes where it stopped.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from dataclasses import field as dc_field
from pathlib import Path
from typing import ClassVar

import numpy as np

from ..core import config as C
from ..core.atomic import write_json, write_text
from ..core.cluster import ClusterConfig, Task, run_tasks
from ..core.errors import ConfigError, RunError
from ..core.folder_lock import folder_lock, holds_work
from ..core.legacy_names import current_name, folder_written_before
from ..data.views import TrainData
from ..eval.metrics import mean_std
from ..train.config import config_diff
from .curves import speed_accuracy
from .methods import METHODS, MethodConfig, get_method, prior_kwargs
from .methods import FLOORS_FOLDER, run_job
from .sizes import TrainSize, method_config


@dataclass
class CompareConfig:
    """What :func:`compare` runs: ``methods`` (names of :data:`rfmitsuba.experiments.methods.METHODS`),
    ``seeds`` (training seeds) and ``train`` (the sizes every method shares, the one sizes
    config of :mod:`rfmitsuba.experiments.sizes`; the defaults are the coherent Gaussian field,
    3000 Stage-1 and 1500 Stage-2 steps)."""

    methods: list[str] = dc_field(default_factory=lambda: ["baseline", "end_to_end", "ours"])

    #: method names that changed (a comparison folder written before still resumes; rfmitsuba.core.config)
    renamed_values: ClassVar[dict] = {"methods": {"baseline_human": "baseline_person"}}
    seeds: list[int] = dc_field(default_factory=lambda: [0, 1, 2])
    train: TrainSize = dc_field(default_factory=TrainSize)

    def __post_init__(self) -> None:
        for m in self.methods:
            get_method(m)
        if not self.methods or not self.seeds:
            raise ConfigError("CompareConfig: methods and seeds must not be empty")
        if len(set(self.seeds)) != len(self.seeds) or len(set(self.methods)) != len(self.methods):
            raise ConfigError("CompareConfig: methods and seeds must not repeat")


def _check_folder(out: Path, cfg: CompareConfig, dataset: Path) -> None:
    f = out / "compare.toml"
    if f.is_file():
        # more seeds or methods may be added to a comparison; the training sizes must not change
        diff = config_diff(C.to_dict(C.load(CompareConfig, f, saved=True).train), C.to_dict(cfg.train), "train.")
        if diff:
            raise RunError(f"output folder {out} holds another comparison: {'; '.join(diff)}. Use another --out "
                           "(nothing was changed)")
        info = json.loads((out / "dataset.json").read_text()) if (out / "dataset.json").is_file() else {}
        if info.get("dataset") and Path(info["dataset"]).resolve() != dataset.resolve():
            raise RunError(f"output folder {out} compares on dataset {info['dataset']}, not {dataset} "
                           "(nothing was changed)")
    elif out.is_dir() and holds_work(out):
        raise RunError(f"{out} is not empty and holds no compare.toml: not a comparison folder (nothing was changed)")


def compare_job(method: str, seed: int, dataset: Path, out: Path, mcfg: MethodConfig, *, quiet: bool = True,
                reevaluate: bool = False) -> dict:
    """One (method, seed) into ``out/seed<seed>/<method>`` by :func:`rfmitsuba.experiments.methods.run_job`
    (skipped when done; a method that builds on another first runs that one: Ours its Baseline,
    Stage 3 its Ours)."""
    prior = get_method(method).builds_on
    if prior:
        compare_job(prior, seed, dataset, out, mcfg, quiet=quiet)
    return run_job(method, dataset, job_folder(out, method, seed), mcfg=mcfg, seed=seed,
                   record={"method": method, "seed": seed}, reevaluate=reevaluate, quiet=quiet,
                   floors_cache=out / FLOORS_FOLDER,
                   **prior_kwargs(method, job_folder(out, prior, seed) if prior else None))


def job_folder(out: Path, method: str, seed: int) -> Path:
    """The folder of a (method, seed) job, ``out/seed<S>/<method>`` (or where a comparison written
    before the method's name changed keeps it: :func:`rfmitsuba.core.legacy_names.folder_written_before`)."""
    return folder_written_before(Path(out) / f"seed{seed}" / method)


def compare(dataset: str | Path, out: str | Path, *, cfg: CompareConfig | None = None, quiet: bool = True,
            progress: bool = True, reevaluate: bool = False, cluster: ClusterConfig | None = None) -> Path:
    """Run (or resume) a comparison; returns the path of ``report.md``.

    ``reevaluate``: evaluate every finished job of the folder again (after the evaluation
    protocol changed; training is not repeated, ``metrics.json`` is rewritten atomically).
    ``cluster``: where the (method, seed) jobs run (:mod:`rfmitsuba.core.cluster`; default
    here, one after another; on Dask, Ours waits for the Baseline of its seed).

    Raises:
        RunError: ``out`` holds another configuration or dataset, or another process is running a
            comparison into it (:mod:`rfmitsuba.core.folder_lock`).
        DatasetError: a dataset without person-present states (the methods need them).
        JobsFailed: (a RunError) on a cluster, jobs failed (each named; the others are done and kept).
    """

    cfg = cfg or CompareConfig()
    cluster = cluster or ClusterConfig()
    dataset, out = Path(dataset), Path(out)
    _check_folder(out, cfg, dataset)
    with folder_lock(out, what="compare"):   # a second compare into out stops here, naming this one
        return _compare(dataset, out, cfg, quiet=quiet, progress=progress, reevaluate=reevaluate, cluster=cluster)


def _compare(dataset: Path, out: Path, cfg: CompareConfig, *, quiet: bool, progress: bool, reevaluate: bool,
             cluster: ClusterConfig) -> Path:
    """:func:`compare` once its folder is checked and locked."""
    # the methods' configuration first: a bad override or dataset leaves the folder as it was
    mcfg = method_config(cfg.train, scene_known=TrainData.open(dataset).scene_xml is not None)
    C.save(cfg, out / "compare.toml")
    write_json(out / "dataset.json", {"dataset": str(dataset.resolve())})

    order = sorted(cfg.methods, key=lambda m: (_depth(m), m))     # each after what it builds on
    jobs = [(m, seed) for seed in cfg.seeds for m in order]
    # jobs of earlier seeds / methods of the same comparison stay in the results
    earlier = []
    for p in sorted(out.glob("seed*/*/DONE")):  # out/seed<S>/<method>/DONE
        method, seed = current_name(p.parent.name), int(p.parent.parent.name[len("seed"):])
        if (method, seed) not in jobs:
            earlier.append((method, seed))
    # workers elsewhere resolve relative paths against their own folder
    ds_arg, out_arg = (dataset, out) if cluster.serial else (dataset.resolve(), out.resolve())
    tasks: list[Task] = []
    for m, seed in jobs + earlier:
        names = {t.name for t in tasks}
        prior = get_method(m).builds_on
        after = tuple(n for n in [_job_name(prior, seed)] if prior and n in names)
        tasks.append(Task(_job_name(m, seed), compare_job, (m, seed, ds_arg, out_arg, mcfg),
                          {"quiet": quiet, "reevaluate": reevaluate}, after=after))
    results = list(run_tasks(tasks, cluster=cluster, desc="compare", unit="job", quiet=not progress).values())
    write_json(out / "results.json", results, allow_nan=True)
    return write_text(out / "report.md", report(results, dataset=dataset, cfg=cfg, out=out))


def summary_by_method(out: str | Path, methods: tuple | list) -> dict:
    """A finished comparison's headline figures, per method over its seeds (results pages).

    Returns:
        {"dataset": path, "name": its room and task with its folder name, "seeds": of the first method,
        "affected_fraction",
        "floors": {"nearest_neighbour", "idw3", "mean_image" (dynamic means), "affected_nearest_neighbour",
        "affected_empty_room"}, and per method {"dynamic": [mean SSIM per seed], "affected": [mean
        where the person matters per seed], "train_s": [seconds per seed], "train": [train summaries]}}.

    Raises:
        RunError: no ``results.json``, or a method without finished jobs.
    """
    out = Path(out)
    if not (out / "results.json").is_file():
        raise RunError(f"{out}: no results.json; run the comparison first")
    results = json.loads((out / "results.json").read_text())
    dataset = Path(json.loads((out / "dataset.json").read_text())["dataset"])
    rows = {m: sorted((r for r in results if r["method"] == m), key=lambda r: r["seed"]) for m in methods}
    missing = [m for m, rs in rows.items() if not rs]
    if missing:
        raise RunError(f"{out}: no finished jobs of {', '.join(missing)}")
    ev = rows[methods[0]][0]["eval"]
    meta = {}
    if (dataset / "meta.json").is_file():
        meta = json.loads((dataset / "meta.json").read_text())
    scene = (meta.get("scene") or {}).get("name") if isinstance(meta.get("scene"), dict) else None
    task = {"rx": "moving RX", "tx": "moving TX"}.get(meta.get("task"))
    name = f"{scene.replace('_', ' ')}, {task} ({dataset.name})" if scene and task else dataset.name
    summary = {"dataset": str(dataset), "name": name, "seeds": [r["seed"] for r in rows[methods[0]]],
               "affected_fraction": ev["affected"]["fraction"],
               "floors": {**{k: ev["dynamic"][k]["mean"] for k in ("nearest_neighbour", "idw3", "mean_image")},
                          "affected_nearest_neighbour": ev["affected"]["nearest_neighbour"]["mean"],
                          "affected_empty_room": ev["affected"]["empty_room"]["mean"]}}
    for m, rs in rows.items():
        summary[m] = {"dynamic": [r["eval"]["dynamic"]["model"]["mean"] for r in rs],
                      "affected": [r["eval"]["affected"]["model"]["mean"] for r in rs],
                      "train_s": [r["train"]["train_time_s"] for r in rs], "train": [r["train"] for r in rs]}
    return summary


def summary_table(summary: dict, labels: dict) -> list[str]:
    """Markdown rows of :func:`summary_by_method`'s figures: each method of ``labels`` (name ->
    row label; mean +- spread over seeds), then the floors."""
    def stat(v) -> str:
        v = np.asarray(v, np.float64)
        return f"{v.mean():.3f}" + (f" ± {v.std():.3f}" if len(v) > 1 else "")

    f = summary["floors"]
    lines = ["| method | dynamic mean SSIM | where the person matters | training (s) |", "|---|---|---|---|"]
    lines += [f"| {label} | {stat(summary[m]['dynamic'])} | {stat(summary[m]['affected'])} | "
              f"{np.mean(summary[m]['train_s']):.0f} |" for m, label in labels.items()]
    return lines + [f"| nearest neighbour | {f['nearest_neighbour']:.3f} | {f['affected_nearest_neighbour']:.3f} | |",
                    f"| IDW-3 | {f['idw3']:.3f} | | |", f"| mean image | {f['mean_image']:.3f} | | |",
                    f"| the empty room's true PAS | | {f['affected_empty_room']:.3f} | |"]


def _depth(method: str) -> int:
    """How many methods ``method`` builds on in a chain (Baseline 0, Ours 1, Stage 3 2)."""
    prior = get_method(method).builds_on
    return 0 if prior is None else 1 + _depth(prior)


def _job_name(method: str, seed: int) -> str:
    """The name of a (method, seed) job: its folder under the comparison, ``seed<S>/<method>``."""
    return f"seed{seed}/{method}"


def _ms(values, digits: int = 3) -> str:
    """``mean ± std`` of finite values (rfmitsuba.eval.metrics.mean_std), the value alone for one, n/a for none."""

    v = [float(x) for x in values if x is not None]
    m, sd = mean_std(v)
    if not np.isfinite(m):
        return "n/a"
    return f"{m:.{digits}f} ± {sd:.{digits}f}" if sum(np.isfinite(v)) > 1 else f"{m:.{digits}f}"


def report(results: list[dict], *, dataset: Path, cfg: CompareConfig, out: Path | None = None) -> str:
    """Markdown: per method, dynamic and static SSIM (mean +- std over seeds of the per-seed mean
    and median), the floors, whether the method beats nearest neighbour, training and render time;
    with ``out``, also speed against accuracy (draws ``out/speed_accuracy.png``)."""
    lines = [f"# Method comparison on `{dataset}`", "",
             f"Seeds {sorted({r['seed'] for r in results})} (of jobs run in this folder; a method's row averages the "
             f"seeds it has); metric protocol (docs/conventions.md) (skimage SSIM, min-max normalised 90 x 360 PAS); mean ± std "
             "over seeds.", ""]
    for part in ("dynamic", "static"):
        lines += [f"## {part.capitalize()} evaluation", "",
                  "| method | mean SSIM | median SSIM | nearest neighbour | IDW-3 | mean image | beats NN | "
                  "train time (s) | render (ms / PAS) | sources / Gaussians |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for m in _method_order(results, cfg):
            rs = [r for r in results if r["method"] == m and r["eval"].get(part)]
            if not rs:
                continue
            ev = [r["eval"][part] for r in rs]
            beats = sum(e["beats_nearest_neighbour"] for e in ev)
            lines.append(
                f"| {METHODS[m].label} | {_ms(e['model']['mean'] for e in ev)} | {_ms(e['model']['median'] for e in ev)}"
                f" | {_ms(e['nearest_neighbour']['mean'] for e in ev)}"
                f" | {_ms(e['idw3']['mean'] if e.get('idw3') else None for e in ev)}"
                f" | {_ms(e['mean_image']['mean'] for e in ev)}"
                f" | {beats}/{len(ev)} | {_ms((r['train']['train_time_s'] for r in rs), 0)}"
                f" | {_ms((r['eval']['render_ms_per_pas'] for r in rs), 1)} | {rs[0]['eval']['num_gaussians']} |")
        lines.append("")
    lines += _affected_lines(results, cfg)
    lines += ["Training time of Ours and Continued includes their Stage 1 (the Baseline of the same seed).", ""]
    if out is not None:
        lines += ["## Speed against accuracy", ""]
        lines += speed_accuracy(Path(out) / "speed_accuracy.png",
                                {Path(dataset).name: [(r["method"], r["seed"], r) for r in results]})
    return "\n".join(lines)


def _method_order(results: list[dict], cfg: CompareConfig) -> list[str]:
    """The report's rows: the configured methods, then those of earlier jobs in this folder."""
    have = {r["method"] for r in results}
    return list(cfg.methods) + [m for m in METHODS if m in have and m not in cfg.methods]


def _affected_lines(results: list[dict], cfg: CompareConfig) -> list[str]:
    """Markdown section: the dynamic evaluation on the PAS the person changes most
    (:func:`rfmitsuba.experiments.methods.evaluate`'s "affected" part; jobs evaluated before it existed are
    left out: ``--reevaluate`` adds it)."""
    rs_all = [r for r in results if r["eval"].get("affected")]
    if not rs_all:
        return []
    a0 = rs_all[0]["eval"]["affected"]
    lines = ["## Where the person matters", "",
             f"Dynamic test PAS whose SSIM against the empty room's PAS at the same antenna is below "
             f"{a0['threshold']:g}: {a0['model']['n']} PAS ({100 * a0['fraction']:.1f}% of the dynamic test set). "
             "\"empty room\" scores the empty room's true PAS as the prediction: what a perfect background "
             "model can reach here.", "",
             "| method | mean SSIM | median SSIM | nearest neighbour | empty room | seeds |", "|---|---|---|---|---|---|"]
    for m in _method_order(rs_all, cfg):
        rs = [r["eval"]["affected"] for r in rs_all if r["method"] == m]
        if rs:
            lines.append(f"| {METHODS[m].label} | {_ms(a['model']['mean'] for a in rs)} | "
                         f"{_ms(a['model']['median'] for a in rs)} | {_ms(a['nearest_neighbour']['mean'] for a in rs)} | "
                         f"{_ms(a['empty_room']['mean'] for a in rs)} | {len(rs)} |")
    return lines + [""]

