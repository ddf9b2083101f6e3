"""One job of a reproduction: a training and evaluation of one method on one dataset with one
seed (and optionally noisy training data, fewer training positions or a shorter walk). Tables
(:mod:`rfmitsuba.experiments.paper_tables`) list their jobs; :mod:`rfmitsuba.experiments.reproduce`
runs each once."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from ..core.legacy_names import folder_written_before
from .methods import get_method
from .sizes import DatasetSpec


@dataclass(frozen=True)
class Job:
    """One training + evaluation: dataset, method, seed, noise SNR (None = clean), training
    antenna positions (0 = all) and how they are laid out ("random" or "grid",
    :meth:`rfmitsuba.data.samples.SampleData.open_samples`), the walk positions it trains on (the
    first ``walk_frames`` of the walk; None = the whole walk, 0 = none), and the dataset it is
    evaluated on (None = the one it trains on; the Rx-count table trains on extra empty-room
    positions and tests on the main dataset)."""

    dataset: DatasetSpec
    method: str
    seed: int
    snr_db: float | None = None
    positions: int = 0
    eval_dataset: DatasetSpec | None = None
    layout: str = "random"
    walk_frames: int | None = None

    @property
    def key(self) -> str:
        k = f"{self.method}_s{self.seed}"
        if self.snr_db is not None:
            k += f"_snr{self.snr_db:g}"
        if self.positions:
            k += f"_n{self.positions}"
        if self.layout != "random":
            k += f"_{self.layout}"
        if self.walk_frames is not None:
            k += f"_w{self.walk_frames}"
        if self.eval_dataset is not None:
            k += f"_on_{self.eval_dataset.key}"
        return k

    def folder(self, out: Path) -> Path:
        """``out/jobs/<dataset>/<key>`` (or where a folder written before a name changed keeps it:
        :func:`rfmitsuba.core.legacy_names.folder_written_before`)."""
        return folder_written_before(Path(out) / "jobs" / self.dataset.key / self.key)

    def prior_job(self) -> "Job | None":
        """The job this one starts from (its method's ``builds_on``: Ours' Baseline, Stage 3's
        Ours), same dataset, seed and variant; None when it trains from scratch. A prior that
        trains on the empty room alone sees none of a shortened walk (``walk_frames`` 0), so the
        jobs of every walk length share it."""
        prior = get_method(self.method).builds_on
        if not prior:
            return None
        empty_only = get_method(prior).states == "empty"
        walk = 0 if empty_only and self.walk_frames is not None else self.walk_frames
        return dataclasses.replace(self, method=prior, walk_frames=walk)

    def record(self) -> dict:
        """What the job's metrics are filed under (``eval_dataset``, ``layout`` and ``walk_frames``
        only where they are not their defaults, so the records of jobs made before them are unchanged)."""
        return {"dataset": self.dataset.key, "scene": self.dataset.scene, "task": self.dataset.task,
                "material": self.dataset.material, "method": self.method, "seed": self.seed,
                "snr_db": "none" if self.snr_db is None else float(self.snr_db), "positions": self.positions,
                **({"eval_dataset": self.eval_dataset.key} if self.eval_dataset is not None else {}),
                **({"layout": self.layout} if self.layout != "random" else {}),
                **({"walk_frames": self.walk_frames} if self.walk_frames is not None else {})}
