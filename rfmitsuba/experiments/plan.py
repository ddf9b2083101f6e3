"""What a reproduction still has to do, and how long that should take, before running it.

``rfmitsuba reproduce --plan`` answers "how long will ``--size full`` take here?" from measured
figures, not from a formula: each job not yet done is estimated by the median wall time
(training + evaluation, ``wall_s`` of ``metrics.json``) of finished jobs of the same kind in
the output folder and in any reference folders (``--plan-from DIR``, e.g. a reproduction run
on the same machine). A job's *kind* is its method and variant without the seed
(:func:`job_kind`: ``baseline``, ``baseline_n180``, ``ours_snr10``,
``baseline_n1800_on_bedroom_rx_tissue``); where no job of that kind was measured, the median
of the same method stands in, and where no job of the method was either, the job is counted as
not estimated. A dataset still to generate is estimated from the generation rate (seconds per
PAS, ``timing.json``) of complete datasets in the data folder and in the reference folders'
``data/``: the same scene and task, else the same scene, else the same task, else any; states
already written are not counted again (:func:`generation_rates`).

With ``workers`` > 1 (``reproduce --plan --workers N``) the plan also gives the wall time of a
run on N single-thread workers (:func:`makespan`): the datasets to generate, then the jobs, in
submission order, each to the first free worker once what it waits for has finished (its
datasets; Ours also its Baseline), as ``reproduce`` submits them. It is as good as its job
times: those of a run on the same number of workers time it best.

Nothing is written: a plan of a folder that does not exist creates none.
"""
from __future__ import annotations

import dataclasses
import heapq
import json
import re
import statistics
from dataclasses import dataclass
from dataclasses import field as dc_field
from pathlib import Path

from ..core.errors import DatasetError
from ..data.store import open_dataset
from .job import Job
from .paper_tables import all_jobs
from .reproduce import check_experiment, dataset_path, dataset_shape, dataset_specs, states_written, truth_checks
from .sizes import ExperimentConfig
from .truth import load_summary, truth_folder


def job_kind(job: Job) -> str:
    """The job's key without its seed: what makes two jobs take about the same time."""
    return _without_seed(job.key)


def _without_seed(key: str) -> str:
    """A job key (:attr:`Job.key`, also its folder's name) without its ``_s<seed>`` part."""
    return re.sub(r"_s\d+", "", key, count=1)


def measured_times(folders: list[Path]) -> dict[str, list[float]]:
    """Wall times [s] of the finished jobs under ``folder/jobs/*/*`` of each folder, by kind
    (:func:`job_kind`, rebuilt from the job folder's name) and by ``method:<name>``."""
    times: dict[str, list[float]] = {}
    for folder in folders:
        for done in sorted(Path(folder).glob("jobs/*/*/DONE")):
            try:
                metrics = json.loads((done.parent / "metrics.json").read_text())
                wall = float(metrics["wall_s"])
                method = str(metrics["job"]["method"])
            except (OSError, ValueError, KeyError, TypeError):
                continue  # a job without readable metrics is not a measurement
            kind = _without_seed(done.parent.name)
            times.setdefault(kind, []).append(wall)
            times.setdefault(f"method:{method}", []).append(wall)
    return times


def generation_rates(folders: list[Path]) -> dict[str, list[float]]:
    """Seconds per PAS of the datasets generated in ``folders`` (each a folder of datasets), from
    each dataset's ``timing.json`` (every generation session: its states and wall time) and
    ``meta.json`` (scene, task, positions); keyed ``scene/task``, ``scene``, ``task:<task>``
    and ``any``. A dataset without readable timing is not a measurement."""
    rates: dict[str, list[float]] = {}
    for folder in folders:
        for timing in sorted(Path(folder).glob("*/timing.json")):
            try:
                sessions = json.loads(timing.read_text())
                meta = json.loads((timing.parent / "meta.json").read_text())
                positions = int(meta["num_antenna_positions"])
                states = sum(int(t["states"]) for t in sessions)
                seconds = sum(float(t["total_s"]) for t in sessions)
                scene, task = str(meta["generate"]["scene"]), str(meta["task"])
            except (OSError, ValueError, KeyError, TypeError):
                continue
            if states <= 0 or positions <= 0 or seconds <= 0:
                continue
            rate = seconds / (states * positions)
            for key in (f"{scene}/{task}", scene, f"task:{task}", "any"):
                rates.setdefault(key, []).append(rate)
    return rates


@dataclass
class DatasetPlan:
    """One dataset the jobs need: where, whether complete, and for one still to generate its
    PAS left and estimated seconds (None: no generation rate measured)."""

    key: str
    path: str
    complete: bool
    pas_left: int = 0
    estimate_s: float | None = None
    #: which generated datasets timed it: "scene/task", "scene", "task:<task>" or "any" (None: none)
    timed_by: str | None = None


@dataclass
class TablePlan:
    """One table: its jobs, those done, those to run, their estimated wall time [s] and how
    many of them have no estimate."""

    table: str
    jobs: int
    done: int
    to_run: int
    estimate_s: float
    unestimated: int


@dataclass
class Plan:
    """The plan of a reproduction (see the module docstring); ``datasets``: every dataset the
    jobs need (:class:`DatasetPlan`); ``total``: the jobs of all tables once."""

    tables: list[TablePlan]
    total: TablePlan
    datasets: list[DatasetPlan]
    measured_jobs: int
    sources: list[str] = dc_field(default_factory=list)
    #: workers of the wall-time estimate (1: one task at a time, the sums above)
    workers: int = 1
    #: estimated wall time [s] on ``workers`` workers, datasets and jobs as submitted (:func:`makespan`);
    #: what is not estimated counts as 0
    makespan_s: float = 0.0
    #: the truth checks the run needs ("room_task"; :func:`rfmitsuba.experiments.reproduce.truth_checks`)
    #: and those of them still to run (not estimated)
    truth_checks: list[str] = dc_field(default_factory=list)
    truth_left: list[str] = dc_field(default_factory=list)


def makespan(durations: list[float], *, workers: int, after: list | None = None, start: float = 0.0) -> float:
    """When the last of ``durations`` [s] ends on ``workers`` workers: whenever a worker is free it
    takes the first task in submission order whose tasks in ``after`` have ended (as Dask runs
    tasks submitted together in priority order), or waits until one has.

    Args:
        durations: task durations [s], in submission order.
        workers: number of workers (>= 1).
        after: per task, what it waits for: the index of an earlier task, a tuple of them, or None.
        start: when every worker becomes free [s].

    Returns:
        The finish time [s] of the last task (``start`` if there is none).
    """
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    deps = [() if a is None else (a,) if isinstance(a, int) else tuple(a)
            for a in (after if after is not None else [None] * len(durations))]
    free = [float(start)] * workers
    heapq.heapify(free)
    end: list[float | None] = [None] * len(durations)
    pending = list(range(len(durations)))
    last = float(start)
    while pending:
        t = heapq.heappop(free)
        ready = next((i for i in pending if all(end[d] is not None and end[d] <= t for d in deps[i])), None)
        if ready is None:   # wait for the next task to end after t (one always will: deps come earlier)
            t = min(e for e in end if e is not None and e > t)
            heapq.heappush(free, t)
            continue
        pending.remove(ready)
        end[ready] = t + float(durations[ready])
        heapq.heappush(free, end[ready])
        last = max(last, end[ready])
    return last


def _estimate(job: Job, times: dict[str, list[float]]) -> float | None:
    for key in (job_kind(job), f"method:{job.method}"):
        if times.get(key):
            return float(statistics.median(times[key]))
    return None


def _complete(path: Path) -> bool:
    try:
        open_dataset(path)
    except (DatasetError, OSError, ValueError):
        return False
    return True


def plan(out: str | Path, cfg: ExperimentConfig, *, data_dir: str | Path | None = None,
         reference: list[str | Path] = (), workers: int = 1) -> Plan:
    """The plan of running ``cfg`` into ``out`` (read only).

    Args:
        out: the reproduction's output folder (need not exist).
        cfg: the experiment.
        data_dir: where its datasets live (default ``out/data``).
        reference: other reproduction folders whose finished jobs time the estimates.
        workers: single-thread workers of the wall-time estimate (:attr:`Plan.makespan_s`).

    Raises:
        RunError: ``out`` holds another experiment configuration (as :func:`reproduce` would).
    """
    out = Path(out)
    check_experiment(out, cfg)
    data_dir = Path(data_dir) if data_dir else out / "data"
    sources = [out] + [Path(r) for r in reference]
    times = measured_times(sources)

    def table(name: str, jobs: list[Job]) -> TablePlan:
        todo = [j for j in jobs if not (j.folder(out) / "DONE").is_file()]
        est = [_estimate(j, times) for j in todo]
        return TablePlan(name, len(jobs), len(jobs) - len(todo), len(todo),
                         float(sum(e for e in est if e is not None)), sum(e is None for e in est))

    tables = [table(t, all_jobs(dataclasses.replace(cfg, tables=[t]))) for t in cfg.tables]
    jobs = all_jobs(cfg)
    specs = dataset_specs(cfg)
    rates = generation_rates([data_dir] + [Path(r) / "data" for r in reference])
    datasets = []
    for spec in specs:
        path = dataset_path(spec, cfg, data_dir)
        if _complete(path):
            datasets.append(DatasetPlan(spec.key, str(path), True))
            continue
        positions, walk = dataset_shape(spec, cfg)
        left = max(1 + walk - states_written(path), 0) * positions
        by = next((k for k in (f"{spec.scene}/{spec.task}", spec.scene, f"task:{spec.task}", "any") if rates.get(k)),
                  None)
        datasets.append(DatasetPlan(spec.key, str(path), False, left,
                                    None if by is None else statistics.median(rates[by]) * left, by))
    measured = sum(len(v) for k, v in times.items() if k.startswith("method:"))
    # one graph as reproduce submits it: the datasets to generate, then the jobs, each job after
    # its datasets (those still to generate) and the job it builds on (if still to run)
    gen = [(spec, d) for spec, d in zip(specs, datasets) if not d.complete]
    todo = [j for j in jobs if not (j.folder(out) / "DONE").is_file()]
    index = {spec: i for i, (spec, _) in enumerate(gen)}
    index.update({j: len(gen) + i for i, j in enumerate(todo)})

    def needs(j: Job) -> tuple:
        return tuple(index[x] for x in (j.dataset, j.eval_dataset, j.prior_job()) if x is not None and x in index)

    wall = makespan([d.estimate_s or 0.0 for _, d in gen] + [_estimate(j, times) or 0.0 for j in todo],
                    workers=workers, after=[None] * len(gen) + [needs(j) for j in todo])
    checks = {f"{r}_{k}": truth_folder(out, r, k) for r, k in truth_checks(cfg)}
    return Plan(tables, table("all", jobs), datasets, measured, [str(s) for s in sources], workers=workers,
                makespan_s=wall, truth_checks=list(checks),
                truth_left=[n for n, f in checks.items() if load_summary(f) is None])


def format_plan(p: Plan) -> str:
    """The plan as Markdown (what ``reproduce --plan`` prints)."""
    missing = [d for d in p.datasets if not d.complete]
    L = [f"Datasets: {len(p.datasets)} needed, {len(p.datasets) - len(missing)} complete, {len(missing)} to generate"]
    if missing:
        known = [d.estimate_s for d in missing if d.estimate_s is not None]
        L += ["", "| dataset to generate | PAS left | estimated wall time (h) | timed by datasets of |", "|---|---|---|---|"]
        L += [f"| {d.key} | {d.pas_left} | {'not estimated' if d.estimate_s is None else f'{d.estimate_s / 3600:.2f}'} "
              f"| {d.timed_by or '-'} |" for d in missing]
        L += [f"| **all** | {sum(d.pas_left for d in missing)} | {sum(known) / 3600:.2f}"
              + (f" ({len(missing) - len(known)} not estimated)" if len(known) < len(missing) else "") + " | |"]
    if p.truth_checks:
        L += ["", f"Truth checks beside the main table: {len(p.truth_checks)} needed, "
              f"{len(p.truth_checks) - len(p.truth_left)} done, {len(p.truth_left)} to run"
              + (f" (not estimated: {', '.join(p.truth_left)})" if p.truth_left else "")]
    L += ["", "| table | jobs | done | to run | estimated wall time (h) | not estimated |", "|---|---|---|---|---|---|"]
    for t in p.tables + [p.total]:
        name = f"**{t.table}**" if t is p.total else t.table
        L.append(f"| {name} | {t.jobs} | {t.done} | {t.to_run} | {t.estimate_s / 3600:.2f} | {t.unestimated} |")
    L += ["", f"Estimates: the median wall time of finished jobs of the same kind (else the same method), "
          f"{p.measured_jobs} jobs measured in {', '.join(p.sources)}; a job shared by tables counts in each, "
          "the total once; one job at a time. Datasets: seconds per PAS of the datasets already generated "
          "(same scene and task, else scene, else task, else any)."]
    total_s = p.total.estimate_s + sum(d.estimate_s or 0.0 for d in missing)
    unknown = p.total.unestimated or any(d.estimate_s is None for d in missing) or p.truth_left
    L += ["", f"Estimated total: {total_s / 3600:.2f} h (datasets + jobs)" + (" plus what is not estimated"
                                                                             if unknown else "") + "."]
    if p.workers > 1:
        L += [f"On {p.workers} single-thread workers (`--workers {p.workers}`): about {p.makespan_s / 3600:.2f} h "
              "wall time" + (" plus what is not estimated" if unknown else "") + " (each dataset and job to the "
              "first free worker once its datasets and the job it builds on are done; as good as the job "
              "times are for one thread)."]
    return "\n".join(L)
