"""The Gaussian-process field against the floors on a folder of measured spectra under many
held-out protocols: the table and figure of docs/results/measured/protocols.md.

Usage: python scripts/measured_protocols.py FOLDER OUT_DIR [--seeds 0 1 2]

The protocols (each a set of training positions and the test positions held out from them):

- ``published``: the folder's own index files;
- ``slab <axis> <low|high>``: the 20 % of positions with the smallest or largest coordinate along
  x, y or z held out (an extrapolation beyond one face of the region);
- ``centre``: the 20 % of positions closest to the centroid held out (a hole to fill);
- ``random <p> % s<seed>``: a random p % of the positions for training (50, 20 and 10 %), per seed.

For each, the field is conditioned on every training spectrum, as ``rfmitsuba train`` leaves it
(:class:`rfmitsuba.models.gaussian_process.GaussianProcessField`), twice: with its default
hyperparameters (the likelihood's, then the leave-one-out scale factor) and with the likelihood's
alone (factor 1). Both are scored on the test spectra beside nearest neighbour, IDW-3 and the mean
image (:func:`rfmitsuba.eval.metrics.floors`). Writes ``protocols.md``, ``protocols.json`` and
``protocols.png`` into OUT_DIR.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

#: held-out share of the slab and centre protocols
HELD_OUT = 0.2
#: training shares of the random protocols
RANDOM_TRAIN = (0.5, 0.2, 0.1)
FLOORS = ("nearest_neighbour", "idw3", "mean_image")
VARIANTS = ("default", "likelihood")
LABEL = {"default": "field (default)", "likelihood": "field, likelihood's scales", "nearest_neighbour": "NN",
         "idw3": "IDW-3", "mean_image": "mean image"}


def margin(row: dict, variant: str) -> float:
    """Mean test SSIM of ``variant`` minus the best floor's in one protocol's row."""
    return row[variant]["mean"] - max(row[k]["mean"] for k in FLOORS)


def protocols(positions: np.ndarray, published: tuple, seeds: list[int]):
    """(name, train indices, test indices) of every protocol for positions float [A, 3] [m]."""
    a = len(positions)
    k = int(round(HELD_OUT * a))
    yield "published", np.asarray(published[0]), np.asarray(published[1])
    for axis, name in enumerate("xyz"):
        order = np.argsort(positions[:, axis], kind="stable")
        yield f"slab {name} high", order[:-k], order[-k:]
        yield f"slab {name} low", order[k:], order[:k]
    order = np.argsort(np.linalg.norm(positions - positions.mean(0), axis=1), kind="stable")
    yield "centre", order[k:], order[:k]
    for share in RANDOM_TRAIN:
        for seed in seeds:
            perm = np.random.default_rng(seed).permutation(a)
            n = int(round(share * a))
            yield f"random {int(share * 100)} % s{seed}", perm[:n], perm[n:]


def score(positions, pas, train, test) -> dict:
    """Mean and median test SSIM of both variants and the floors, and the chosen factor."""
    from rfmitsuba.core.ssim import ssim_images
    from rfmitsuba.eval.metrics import floors
    from rfmitsuba.models.gaussian_process import GaussianProcessField
    from rfmitsuba.rf.bartlett_ref import normalize

    out = {"train": int(len(train)), "test": int(len(test))}
    f = GaussianProcessField(height=pas.shape[1], width=pas.shape[2])
    hyper = f.condition(positions[train], pas[train])
    out["scale_factor"] = hyper["scale_factor"]
    ssim = {"default": ssim_images(normalize(f.predict(positions[test])), pas[test])}
    g = GaussianProcessField(height=pas.shape[1], width=pas.shape[2])
    g.condition(positions[train], pas[train],
                hyper={"length_scales_m": hyper["likelihood_length_scales_m"], "nugget": hyper["nugget"]})
    ssim["likelihood"] = ssim_images(normalize(g.predict(positions[test])), pas[test])
    fl = floors(pas[train], positions[train], pas[test], positions[test])
    ssim.update({k: fl[k] for k in FLOORS})
    for k, v in ssim.items():
        out[k] = {"mean": float(np.mean(v)), "median": float(np.median(v))}
    return out


def summary(rows: dict) -> list[str]:
    """Per variant: protocols whose mean beats the best floor's, the mean over protocols, the worst
    margin to the best floor."""
    lines = []
    for v in VARIANTS:
        margins = [margin(r, v) for r in rows.values()]
        wins = sum(m > 0 for m in margins)
        worst = min(rows, key=lambda n: margin(rows[n], v))
        lines.append(f"- {LABEL[v]}: beats the best floor in mean in **{wins} of {len(rows)}** protocols; "
                     f"mean over the protocols {np.mean([r[v]['mean'] for r in rows.values()]):.3f} "
                     f"(median {np.mean([r[v]['median'] for r in rows.values()]):.3f}); worst margin to the best "
                     f"floor {min(margins):+.3f} ({worst})")
    floors_mean = "; ".join(f"{LABEL[k]} {np.mean([r[k]['mean'] for r in rows.values()]):.3f}" for k in FLOORS)
    return lines + [f"- the floors' means over the protocols: {floors_mean}"]


def figure(rows: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(rows)
    y = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(7, 0.32 * len(names) + 1.2))
    for off, v, colour in ((-0.18, "default", "tab:blue"), (0.18, "likelihood", "tab:gray")):
        ax.barh(y + off, [margin(rows[n], v) for n in names], height=0.34, color=colour, label=LABEL[v])
    ax.axvline(0, color="k", lw=0.8)
    ax.set_yticks(y, names)
    ax.invert_yaxis()
    ax.set_xlabel("mean test SSIM minus the best of NN, IDW-3 and the mean image")
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    a = ap.parse_args()
    from tqdm import tqdm

    from rfmitsuba.data.store import open_dataset

    ds = open_dataset(a.folder)
    positions, pas = np.asarray(ds.antenna_pos, np.float64), np.asarray(ds.pas(0), np.float32)
    todo = list(protocols(positions, (ds.split.antenna_train, ds.split.antenna_test), a.seeds))
    rows = {name: score(positions, pas, tr, te) for name, tr, te in tqdm(todo, desc="protocols")}
    a.out_dir.mkdir(parents=True, exist_ok=True)
    (a.out_dir / "protocols.json").write_text(json.dumps(rows, indent=1))
    cols = (*VARIANTS, *FLOORS)
    lines = ["# Measured spectra: the Gaussian-process field under many held-out protocols", "",
             f"The folder `{a.folder.name}` ({len(positions)} spectra). Each protocol conditions the field on "
             "its training spectra, as `rfmitsuba train` leaves it, and scores mean / median test SSIM. "
             "*field (default)*: the likelihood's length scales times the factor of the best leave-one-out "
             "SSIM; *field, likelihood's scales*: factor 1. Bold: the best mean of the row.", "",
             *summary(rows), "", "![margin to the best floor per protocol](protocols.png)", "",
             "| protocol | train / test | " + " | ".join(LABEL[c] for c in cols) + " | factor |",
             "|---|---|" + "---|" * len(cols) + "---|"]
    for name, r in rows.items():
        best = max(cols, key=lambda c: r[c]["mean"])
        cells = [(f"**{r[c]['mean']:.3f}**" if c == best else f"{r[c]['mean']:.3f}") + f" / {r[c]['median']:.3f}"
                 for c in cols]
        lines.append(f"| {name} | {r['train']} / {r['test']} | " + " | ".join(cells) + f" | {r['scale_factor']:g} |")
    lines += ["", "## Reproduce", "", "```bash",
              f"python scripts/measured_protocols.py {a.folder.name} docs/results/measured   # a few minutes on 2 cores",
              "```", ""]
    (a.out_dir / "protocols.md").write_text("\n".join(lines))
    figure(rows, a.out_dir / "protocols.png")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
