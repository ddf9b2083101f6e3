"""The paper's tables, one object each and one module each: its jobs, its report section and its
claims.

A :class:`Table` (``base``) says which jobs (:class:`rfmitsuba.experiments.job.Job`) it needs for
one seed (:meth:`Table.jobs`) and writes its Markdown section from the finished jobs' results,
adding its verdicts on the paper's claims (:meth:`Table.section`). :data:`TABLES` holds them by
the names of :data:`rfmitsuba.experiments.sizes.TABLES`; ``reproduce`` runs the union of their
jobs (:func:`all_jobs`) and ``report`` writes their sections in order. A new table is one module
here with one :class:`Table` subclass, added to :data:`TABLES` and to ``sizes.TABLES``.
"""
from __future__ import annotations

from ..job import Job
from ..sizes import TABLES as TABLE_NAMES
from ..sizes import ExperimentConfig
from .base import ReferenceTable, Table, plots_colours, reference_dataset
from .data_scarce import DataScarceTable
from .large_room import LargeRoomTable
from .main import MainTable, truth_band
from .material import MaterialTable
from .noise import NoiseTable
from .perturbation import PerturbationTable
from .positions import PositionsTable
from .rx_count import RxCountTable, static_positions_for
from .third_stage import ThirdStageTable
from .two_stage import TwoStageTable

#: every table by its name in ``ExperimentConfig.tables``, in the report's order
TABLES: dict[str, Table] = {t.key: t for t in (MainTable(), TwoStageTable(), PerturbationTable(), MaterialTable(),
                                                LargeRoomTable(), PositionsTable(), NoiseTable(), RxCountTable(),
                                                ThirdStageTable(), DataScarceTable())}
assert tuple(TABLES) == tuple(TABLE_NAMES), "paper_tables.TABLES and sizes.TABLES must name the same tables"

__all__ = ["TABLES", "DataScarceTable", "LargeRoomTable", "MainTable", "MaterialTable", "NoiseTable",
           "PerturbationTable", "PositionsTable", "ReferenceTable", "RxCountTable", "Table",
           "ThirdStageTable", "TwoStageTable", "all_jobs", "plots_colours", "reference_dataset",
           "static_positions_for", "table_jobs", "truth_band"]


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
