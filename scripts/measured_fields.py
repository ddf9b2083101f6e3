"""The default field on a folder of measured spectra, both splits, several seeds: the table and
figure of docs/results/measured/fields.md.

Usage: python scripts/measured_fields.py FOLDER RUNS_DIR OUT_DIR [--seeds 0 1 2] [--time-limit-s 500]

For each split ("dataset": the folder's published index files; "block": the 20 % of positions
with the largest x held out) and seed, runs what a user runs::

    rfmitsuba train FOLDER --out RUNS_DIR/<split>_s<seed> --set split=<split> --set seed=<seed> --set time_limit_s=...
    rfmitsuba eval RUNS_DIR/<split>_s<seed>

(resumable: a finished run is not trained again), then writes into OUT_DIR:

- ``fields.md``: per split, the model (and what ``auto`` chose), its fit at the training positions
  and its leave-one-out SSIM there (Gaussian-process field), the neighbour floors and the mean
  image, mean +- spread over the seeds, parameters and training seconds; and the mean SSIM per
  quartile of the distance to the nearest training position, model against the floors;
- ``fields.json``: the same numbers;
- ``fields.png``: measured, predicted and nearest-neighbour spectra of four test positions per split.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

SPLITS = ("dataset", "block")
METHODS = ("model", "nearest_neighbour", "idw3", "mean_image")
LABEL = {"model": "model", "nearest_neighbour": "nearest neighbour", "idw3": "IDW-3", "mean_image": "mean image"}


def run_one(folder: Path, run: Path, split: str, seed: int, time_limit_s: float) -> dict:
    exe = [str(Path(sys.executable).with_name("rfmitsuba"))]
    if not (run / "final" / "summary.json").is_file():
        subprocess.run(exe + ["train", str(folder), "--out", str(run), "--set", f'split="{split}"',
                              "--set", f"seed={seed}", "--set", f"time_limit_s={time_limit_s}", "--quiet"], check=True)
    if not (run / "eval" / "metrics.json").is_file():
        subprocess.run(exe + ["eval", str(run)], check=True, stdout=subprocess.DEVNULL)
    return json.loads((run / "eval" / "metrics.json").read_text())


def loo_ssim(run: Path, data, renderer) -> float | None:
    """Leave-one-out mean SSIM of a Gaussian-process field at its conditioning positions (None for
    another field); ``data`` and ``renderer`` as :func:`rfmitsuba.train.trainer.load_run` gives them."""
    from rfmitsuba.core.ssim import ssim_images
    from rfmitsuba.rf.bartlett_ref import normalize

    f = renderer.fields[0]
    if f.kind != "gaussian_process":
        return None
    summary = json.loads((run / "final" / "summary.json").read_text())
    on = summary.get("conditioned_on") or json.loads((run / "split.json").read_text())["fit"]
    return float(np.mean(ssim_images(normalize(f.loo_predictions()), data.pas(np.asarray(on, np.int64)))))


def quartiles(run: Path, data) -> dict:
    """Mean SSIM per quartile of the distance to the nearest training position, every method."""
    z = np.load(run / "eval" / "ssim.npz")
    split = json.loads((run / "split.json").read_text())
    test = z["test_index"]
    train = np.asarray(split["train"], np.int64)
    d = np.linalg.norm(data.antenna_pos[test][:, None] - data.antenna_pos[train][None], axis=-1).min(1)
    edges = np.quantile(d, [0, 0.25, 0.5, 0.75, 1.0])
    q = np.clip(np.searchsorted(edges, d, side="right") - 1, 0, 3)
    return {"edges_m": edges.tolist(), **{m: [float(z[m][q == i].mean()) for i in range(4)] for m in METHODS}}


def oracles(run: Path, data) -> dict:
    """Two upper bounds that know each test spectrum, mean and median SSIM: the best single training
    spectrum per test spectrum, and the best of the model, nearest neighbour and mean image per test
    spectrum (what a perfect chooser among the three would score)."""
    from rfmitsuba.core.ssim import ssim_images

    z = np.load(run / "eval" / "ssim.npz")
    test = z["test_index"]
    train = np.asarray(json.loads((run / "split.json").read_text())["train"], np.int64)
    gt = data.pas(test)
    best = np.max([ssim_images(np.broadcast_to(img, gt.shape), gt) for img in data.pas(train)], axis=0)
    chooser = np.max([z[k] for k in ("model", "nearest_neighbour", "mean_image")], axis=0)
    return {k: {"mean": float(v.mean()), "median": float(np.median(v))}
            for k, v in (("oracle_training_image", best), ("oracle_chooser", chooser))}


ORACLES = {"oracle_training_image": "*oracle: the best training spectrum per test spectrum*",
           "oracle_chooser": "*oracle: the best of model, nearest neighbour, mean image per test spectrum*"}


def figure(runs: dict, out: Path) -> None:
    from rfmitsuba.core import plots
    from rfmitsuba.train.trainer import load_run

    from rfmitsuba.rf.bartlett_ref import normalize

    fig, axes = plots.subplots(4, 6, figsize=(18, 7))
    for c, split in enumerate(SPLITS):
        run = runs[split]
        _, data, renderer = load_run(run)
        z = np.load(run / "eval" / "ssim.npz")
        test = z["test_index"]
        pick = np.argsort(z["model"])[np.linspace(0, len(test) - 1, 4).astype(int)]
        train = np.asarray(json.loads((run / "split.json").read_text())["train"], np.int64)
        pred = normalize(renderer.render(data, test[pick]))
        for r, (i, p) in enumerate(zip(pick, pred)):
            nn = train[np.argmin(np.linalg.norm(data.antenna_pos[train] - data.antenna_pos[test[i]], axis=1))]
            row = [(data.pas([test[i]])[0], f"{split} split: measured"), (p, f"model, SSIM {z['model'][i]:.3f}"),
                   (data.pas([nn])[0], f"nearest neighbour, SSIM {z['nearest_neighbour'][i]:.3f}")]
            for k, (img, title) in enumerate(row):
                plots.pas_panel(axes[r, 3 * c + k], img, title=title, left=(c == 0 and k == 0), bottom=(r == 3),
                                elevation_start_deg=0.0)
    plots.save(fig, out, dpi=80)


def stat(values: list, *, digits: int = 3) -> str:
    v = np.asarray([x for x in values if x is not None], np.float64)
    if not len(v):
        return "–"
    return f"{v.mean():.{digits}f}" + (f" ± {v.std():.{digits}f}" if len(v) > 1 else "")


INTRO = """# Measured spectra: the default field on both splits

What `rfmitsuba train` (no `--model`: `auto` chooses) and `rfmitsuba eval` give on the measured
NeRF2 RFID folder `{folder}` (200 spectra of one tag, a 4 x 4 gateway about 5 m away; the folder is
`data_test200/` of the public WRF-GS repository), under its published 160/40 split and under the
spatial-block split (the 20 % of positions with the largest x held out). Seeds {seeds}; mean ± standard
deviation over the seeds. The seed changes the validation positions and the trials; the splits are fixed.

On this folder `auto` chooses the Gaussian-process field (`rfmitsuba.models.gaussian_process`), which
interpolates the measured spectra with a kernel fitted by maximum likelihood. Its fit at its own
training positions is an interpolator's (close to 1 by construction); the leave-one-out SSIM, each
conditioning spectrum predicted from all the others, is the figure that says how well it fits.

![measured, predicted and nearest-neighbour spectra](fields.png)

Four test positions per split (the rows: the model's lowest, two middle and its highest test SSIM).

The two *oracle* rows know each test spectrum and are not methods: they bound what any prediction
built from the training spectra, or any rule choosing between the model and the floors, can score.
"""

REPRODUCE = """## Reproduce

```bash
python scripts/measured_fields.py data_test200 runs/measured_fields docs/results/measured   # about 20 min on 2 cores
```

It runs `rfmitsuba train data_test200 --out RUN --set split=... --set seed=...` and `rfmitsuba eval RUN`
for each split and seed (resumable) and writes this page, `fields.json` and `fields.png`.
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("runs_dir", type=Path)
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--time-limit-s", type=float, default=500.0)
    a = ap.parse_args()
    from rfmitsuba.train.trainer import load_run

    a.out_dir.mkdir(parents=True, exist_ok=True)
    result, first = {}, {}
    for split in SPLITS:
        rows = []
        for seed in a.seeds:
            run = a.runs_dir / f"{split}_s{seed}"
            m = run_one(a.folder, run, split, seed, a.time_limit_s)
            chosen = json.loads((run / "final" / "summary.json").read_text())["model"]
            _, data, renderer = load_run(run)
            rows.append({"seed": seed, "chosen": chosen, "loo": loo_ssim(run, data, renderer),
                         "quartiles": quartiles(run, data), **oracles(run, data),
                         **{k: m[k] for k in (*METHODS, "fit", "num_parameters", "train_time_s", "anchored")}})
            first.setdefault(split, run)
        result[split] = rows
    (a.out_dir / "fields.json").write_text(json.dumps(result, indent=1))
    lines = [INTRO.format(folder=a.folder.name, seeds=", ".join(map(str, a.seeds)))]
    for split, rows in result.items():
        lines += [f"## Split: {split}", "",
                  "| method | mean SSIM | median SSIM | per seed (mean) |", "|---|---|---|---|"]
        for k in METHODS:
            per = ", ".join(f"{r[k]['mean']:.4f}" for r in rows)
            lines.append(f"| {LABEL[k]} | {stat([r[k]['mean'] for r in rows])} | "
                         f"{stat([r[k]['median'] for r in rows])} | {per} |")
        for k, label in ORACLES.items():
            lines.append(f"| {label} | {stat([r[k]['mean'] for r in rows])} | {stat([r[k]['median'] for r in rows])} | "
                         + ", ".join(f"{r[k]['mean']:.4f}" for r in rows) + " |")
        chosen = sorted({r["chosen"] for r in rows})
        lines += ["", f"- `auto` chose: {', '.join(chosen)}",
                  f"- fit at its own training positions: {stat([r['fit']['mean'] for r in rows])}; "
                  f"leave-one-out at the conditioning positions: {stat([r['loo'] for r in rows])}",
                  f"- fitted parameters: {stat([r['num_parameters'] for r in rows], digits=0)}; training of the chosen "
                  f"field: {stat([r['train_time_s'] for r in rows], digits=1)} s (after the trials)", "",
                  "| distance to the nearest training position (seed %d) | model | nearest neighbour | IDW-3 | mean image |"
                  % rows[0]["seed"], "|---|---|---|---|---|"]
        qd = rows[0]["quartiles"]
        for i in range(4):
            lines.append(f"| {qd['edges_m'][i]:.3f}–{qd['edges_m'][i + 1]:.3f} m | "
                         + " | ".join(f"{qd[k][i]:.3f}" for k in METHODS) + " |")
        lines.append("")
    lines.append(REPRODUCE)
    (a.out_dir / "fields.md").write_text("\n".join(lines))
    figure(first, a.out_dir / "fields.png")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
