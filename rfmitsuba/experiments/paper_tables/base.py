"""The base of every paper table (:class:`Table`: its jobs per seed, its report section, its
figures) and what several tables share."""
from __future__ import annotations

from pathlib import Path

from ..job import Job
from ..results import Claims
from ..sizes import DatasetSpec, ExperimentConfig


def reference_dataset(cfg: ExperimentConfig) -> DatasetSpec:
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


class ReferenceTable(Table):
    """A table of the fixed ``methods`` on the reference dataset (:func:`reference_dataset`), one
    job each per seed: the ablations."""

    methods: tuple[str, ...] = ()

    def jobs(self, cfg: ExperimentConfig, seed: int) -> list[Job]:
        return [Job(reference_dataset(cfg), m, seed) for m in self.methods]


def plots_colours(n: int) -> list:
    """``n`` colours from light to dark, the longest walk darkest."""
    from matplotlib import colormaps

    cmap = colormaps["viridis"]
    return [cmap(0.85 - 0.7 * i / max(n - 1, 1)) for i in range(n)]
