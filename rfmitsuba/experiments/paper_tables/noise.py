"""Measurement noise on the training channels at each SNR (not in the paper)."""
from __future__ import annotations

from ..job import Job
from ..results import (
    DYN,
    DYN_IDW,
    DYN_IDW_NOISY,
    DYN_NN,
    DYN_NN_NOISY,
    Claims,
    fmt,
    select,
)
from ..sizes import ExperimentConfig
from .base import Table, reference_dataset


class NoiseTable(Table):
    """Measurement noise on the training channels at each SNR (not in the paper)."""

    key = "noise"

    def jobs(self, cfg: ExperimentConfig, seed: int) -> list[Job]:
        return [Job(reference_dataset(cfg), m, seed, snr_db=snr) for snr in [None] + list(cfg.snr_db)
                for m in ("baseline", "end_to_end", "ours")]

    def section(self, cfg: ExperimentConfig, results: dict, claims: Claims) -> list[str]:
        room, task = cfg.rooms[0], cfg.tasks[0]
        ref = reference_dataset(cfg).key
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
