"""What a reproduction still has to do, and how long that should take, before running it.

``rfmitsuba reproduce --plan`` answers "how long will ``--size full`` take here?" from measured
figures, not from a formula: each job not yet done is estimated by the median wall time
(training + evaluation, ``wall_s`` of ``metrics.json``) of finished jobs of the same kind in
the output folder and in any reference folders (``--plan-from DIR``, e.g. a reproduction run
on the same machine). A job's *kind* is its method and variant without the seed
(:func:`job_kind`: ``baseline``, ``baseline_n180``, ``ours_snr10``,
``baseline_n1800_on_bedroom_rx_tissue``); where no job of that kind was measured, the median
of the same method stands in, and where no job of the method was either, the job is counted as
not estimated. Dataset generation is listed, not estimated.

Nothing is written: a plan of a folder that does not exist creates none.
"""
from __future__ import annotations

import dataclasses
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
from .reproduce import check_experiment, dataset_path
from .sizes import ExperimentConfig


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
    """The plan of a reproduction (see the module docstring); ``datasets``: (key, path,
    complete) of every dataset the jobs need; ``total``: the jobs of all tables once."""

    tables: list[TablePlan]
    total: TablePlan
    datasets: list[tuple[str, str, bool]]
    measured_jobs: int
    sources: list[str] = dc_field(default_factory=list)


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
         reference: list[str | Path] = ()) -> Plan:
    """The plan of running ``cfg`` into ``out`` (read only).

    Args:
        out: the reproduction's output folder (need not exist).
        cfg: the experiment.
        data_dir: where its datasets live (default ``out/data``).
        reference: other reproduction folders whose finished jobs time the estimates.

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
    specs = list(dict.fromkeys([j.dataset for j in jobs] + [j.eval_dataset for j in jobs if j.eval_dataset]))
    paths = {s.key: dataset_path(s, cfg, data_dir) for s in specs}
    datasets = [(k, str(path), _complete(path)) for k, path in paths.items()]
    measured = sum(len(v) for k, v in times.items() if k.startswith("method:"))
    return Plan(tables, table("all", jobs), datasets, measured, [str(s) for s in sources])


def format_plan(p: Plan) -> str:
    """The plan as Markdown (what ``reproduce --plan`` prints)."""
    missing = [(k, path) for k, path, ok in p.datasets if not ok]
    L = [f"Datasets: {len(p.datasets)} needed, {len(p.datasets) - len(missing)} complete"
         + (f", {len(missing)} to generate (not estimated): " + ", ".join(k for k, _ in missing) if missing else ""),
         "", "| table | jobs | done | to run | estimated wall time (h) | not estimated |", "|---|---|---|---|---|---|"]
    for t in p.tables + [p.total]:
        name = f"**{t.table}**" if t is p.total else t.table
        L.append(f"| {name} | {t.jobs} | {t.done} | {t.to_run} | {t.estimate_s / 3600:.2f} | {t.unestimated} |")
    L += ["", f"Estimates: the median wall time of finished jobs of the same kind (else the same method), "
          f"{p.measured_jobs} jobs measured in {', '.join(p.sources)}; a job shared by tables counts in each, "
          "the total once; one job at a time."]
    return "\n".join(L)
