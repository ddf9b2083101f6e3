"""How much of the ground truth do fewer ray samples lose? (docs/lab-notes/paper-tables.md, 2026-11-26)

Traces the empty room of a generated dataset at its first ``--positions`` antenna positions
with several ``samples_per_src`` settings (one thread, as ``generate`` does) and prints, per
setting, the solve's CPU time and the metric's SSIM of its PAS against those of 1e5 and 2e5
samples.

    .venv/bin/python scripts/samples_ssim.py DATASET [--positions 200] [--samples 50000 30000 20000 10000]
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import rfmitsuba  # noqa: F401  (libLLVM before Dr.Jit)
from rfmitsuba.core.ssim import ssim_images
from rfmitsuba.rf import bartlett_ref
from rfmitsuba.sim.simulate import Simulator, SolverConfig

REFERENCES = (100_000, 200_000)


def min_max(pas: np.ndarray) -> np.ndarray:
    """Each PAS of float [K, H, W] min-max normalised on its own (the metric protocol)."""
    flat = pas.reshape(len(pas), -1)
    lo, hi = flat.min(1, keepdims=True), flat.max(1, keepdims=True)
    return ((flat - lo) / np.maximum(hi - lo, 1e-30)).reshape(pas.shape)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dataset", type=Path, help="a dataset folder of `rfmitsuba generate` (task rx or tx)")
    p.add_argument("--positions", type=int, default=200)
    p.add_argument("--samples", type=int, nargs="*", default=[50_000, 30_000, 20_000, 10_000])
    args = p.parse_args()
    meta = json.loads((args.dataset / "meta.json").read_text())
    pos = np.load(args.dataset / "antenna_pos.npy").astype(np.float64)[:args.positions]
    pas = {}
    for samples in (*REFERENCES, *args.samples):
        sim = Simulator(meta["scene"]["file"], fixed_pos=meta["fixed_pos"], frequency_hz=meta["frequency_hz"],
                        solver=SolverConfig(samples_per_src=samples))
        sim.set_positions(pos)
        t = time.process_time()
        h = sim.channels(meta["task"])
        cpu = time.process_time() - t
        pas[samples] = min_max(bartlett_ref.bartlett(h, frequency_hz=meta["frequency_hz"]))
        cells = []
        for ref in REFERENCES:
            if ref == samples or ref not in pas:
                cells.append("-")
                continue
            s = ssim_images(pas[samples], pas[ref])
            cells.append(f"{s.mean():.4f} / {s.min():.3f}")
        print(f"| {samples} | {cpu:.1f} | {cells[0]} | {cells[1]} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
