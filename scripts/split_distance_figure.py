"""Test SSIM against the distance to the nearest training position, for groups of finished,
evaluated runs on one split, beside the nearest-neighbour and IDW-3 floors.

Usage: python scripts/split_distance_figure.py OUT.png LABEL=RUN[,RUN...] [LABEL=RUN,...] [--bins 4]

Every run of a group must be trained on the same dataset and split (``rfmitsuba train ... --split
block``, then ``rfmitsuba eval RUN``); the figure bins the test positions by their distance to
the nearest training position (equal counts per bin) and plots each group's mean SSIM per bin
(the mean over its runs) and the floors of the first run. Made
docs/results/coherent_field/nerf2like_block_by_distance.png from the lab run 53 runs of the lab notes
(docs/lab-notes/nerf2like.md, 2026-11-29).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def _load(run: Path) -> dict:
    from rfmitsuba.core.errors import RunError

    z, m, sp = run / "eval" / "ssim.npz", run / "eval" / "metrics.json", run / "split.json"
    for p in (z, m, sp):
        if not p.is_file():
            raise RunError(f"{run}: {p.name} is missing (train and `rfmitsuba eval` the run first)")
    with np.load(z) as d:
        out = {k: np.asarray(d[k]) for k in d.files}
    out["dataset"] = json.loads(m.read_text())["dataset"]
    out["train"] = np.asarray(json.loads(sp.read_text())["train"], np.int64)
    return out


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from rfmitsuba.data.views import TrainData

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("groups", nargs="+", help="LABEL=RUN[,RUN...]")
    ap.add_argument("--bins", type=int, default=4)
    a = ap.parse_args()
    groups = []
    for g in a.groups:
        label, _, runs = g.partition("=")
        if not runs:
            raise SystemExit(f"group {g!r}: expected LABEL=RUN[,RUN...]")
        groups.append((label, [_load(Path(r)) for r in runs.split(",")]))
    first = groups[0][1][0]
    data = TrainData.open(first["dataset"])
    pos = data.antenna_pos
    test, train = first["test_index"], first["train"]
    dist = np.min(np.linalg.norm(pos[test][:, None] - pos[train][None], axis=-1), axis=1)
    edges = np.quantile(dist, np.linspace(0, 1, a.bins + 1))
    which = np.clip(np.searchsorted(edges, dist, side="right") - 1, 0, a.bins - 1)
    centre = [100 * dist[which == b].mean() for b in range(a.bins)]

    def binned(values):
        return [values[which == b].mean() for b in range(a.bins)]

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for label, runs in groups:
        for r in runs:
            if not np.array_equal(r["test_index"], test):
                raise SystemExit(f"group {label!r}: a run has other test positions than the first run")
        per_run = np.array([binned(r["model"]) for r in runs])
        mean = np.array([r["model"].mean() for r in runs])
        ax.errorbar(centre, per_run.mean(0), yerr=per_run.std(0), marker="o", capsize=3,
                    label=f"{label}: {mean.mean():.3f} ({len(runs)} runs)")
    for key, name, style in (("nearest_neighbour", "nearest neighbour", "k--"), ("idw3", "IDW-3", "k:")):
        ax.plot(centre, binned(first[key]), style, label=f"{name}: {first[key].mean():.3f}")
    ax.set_xlabel("distance to the nearest training position (cm), bin means")
    ax.set_ylabel("test SSIM, bin mean")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(a.out, dpi=110)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
