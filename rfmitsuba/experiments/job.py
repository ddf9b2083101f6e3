"""One job of a reproduction: a training and evaluation of one method on one dataset with one
seed (and optionally noisy training data or fewer training positions). Tables
(:mod:`rfmitsuba.experiments.paper_tables`) list their jobs; :mod:`rfmitsuba.experiments.reproduce`
runs each once."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from .methods import get_method
from .sizes import DatasetSpec


@dataclass(frozen=True)
class Job:
    """One training + evaluation: dataset, method, seed, noise SNR (None = clean), training
    antenna positions (0 = all), and the dataset it is evaluated on (None = the one it trains on;
    the Rx-count table trains on extra empty-room positions and tests on the main dataset)."""

    dataset: DatasetSpec
    method: str
    seed: int
    snr_db: float | None = None
    positions: int = 0
    eval_dataset: DatasetSpec | None = None

    @property
    def key(self) -> str:
        k = f"{self.method}_s{self.seed}"
        if self.snr_db is not None:
            k += f"_snr{self.snr_db:g}"
        if self.positions:
            k += f"_n{self.positions}"
        if self.eval_dataset is not None:
            k += f"_on_{self.eval_dataset.key}"
        return k

    def folder(self, out: Path) -> Path:
        return Path(out) / "jobs" / self.dataset.key / self.key

    def prior_job(self) -> "Job | None":
        """The job this one starts from (its method's ``builds_on``: Ours' Baseline, Stage 3's
        Ours), same dataset, seed and variant; None when it trains from scratch."""
        prior = get_method(self.method).builds_on
        return dataclasses.replace(self, method=prior) if prior else None

    def record(self) -> dict:
        """What the job's metrics are filed under (``eval_dataset`` only when it is not ``dataset``)."""
        return {"dataset": self.dataset.key, "scene": self.dataset.scene, "task": self.dataset.task,
                "material": self.dataset.material, "method": self.method, "seed": self.seed,
                "snr_db": "none" if self.snr_db is None else float(self.snr_db), "positions": self.positions,
                **({"eval_dataset": self.eval_dataset.key} if self.eval_dataset is not None else {})}
