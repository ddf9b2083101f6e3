"""Stage-1 experiments made of several runs: the motivation table and the parsimony curve.

* :func:`motivation_table` - test SSIM against the number of static antenna positions
  (paper, Table "motivation": 900, 1500, 3600, 6000, 10000 positions). A row with C positions
  trains on ``round(0.8 * C)`` positions drawn from the dataset's training split (the 80/20 rule
  of docs/conventions.md) and is evaluated on the dataset's whole test split, the same for every row, so rows
  are comparable. The dataset must hold enough training positions for the largest row.
* :func:`parsimony_curve` - test SSIM against the number of Gaussians ("a model no larger than
  the scene needs"): splat runs whose density control is capped at different sizes, or coherent
  Gaussian runs with different numbers of scatterers; :func:`knee` picks the knee of the curve.

Each run is an ordinary run folder ``OUT/<name>`` (resumable, evaluated by
:func:`rfmitsuba.eval.run.evaluate_run`); the table is written to ``OUT/table.md`` and
``OUT/table.json`` with a plot.
"""
from __future__ import annotations

import json
from pathlib import Path

from ..core import config as C
from ..core import plots
from ..core.errors import ConfigError
from ..data.views import TrainData
from ..eval.run import evaluate_run
from ..train.config import TrainConfig
from ..train.trainer import Trainer

MOTIVATION_COUNTS = (900, 1500, 3600, 6000, 10000)
QUICK_MOTIVATION_COUNTS = (150, 300, 600, 900)


def _run_and_eval(cfg: TrainConfig, data: TrainData, run_dir: Path, *, quiet: bool) -> dict:

    Trainer(cfg, data, run_dir, quiet=quiet).run()
    return evaluate_run(run_dir)


def _write_table(out: Path, title: str, key: str, rows: list[dict], note: str) -> None:
    lines = [f"# {title}", "", note, "",
             f"| {key} | train positions | Gaussians | parameters | mean SSIM | median SSIM | NN mean | NN median | "
             "IDW-3 mean | mean image | train s |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r[key]} | {r['train_positions']} | {r['num_gaussians']} | {r['num_parameters']} | "
                     f"{r['mean']:.4f} | {r['median']:.4f} | {r['nn_mean']:.4f} | {r['nn_median']:.4f} | "
                     f"{r['idw3_mean']:.4f} | {r['mean_image_mean']:.4f} | {r['train_time_s']:.0f} |")
    (out / "table.md").write_text("\n".join(lines) + "\n")
    (out / "table.json").write_text(json.dumps(rows, indent=1))


def _row(m: dict) -> dict:
    return {"mean": m["model"]["mean"], "median": m["model"]["median"], "nn_mean": m["nearest_neighbour"]["mean"],
            "nn_median": m["nearest_neighbour"]["median"], "idw3_mean": m["idw3"]["mean"],
            "mean_image_mean": m["mean_image"]["mean"], "num_gaussians": m["num_gaussians"],
            "num_parameters": m["num_parameters"], "train_time_s": m["train_time_s"],
            "train_positions": m["train_positions"]}


def motivation_table(dataset: str | Path, out: str | Path, *, counts=MOTIVATION_COUNTS,
                     cfg: TrainConfig | None = None, quiet: bool = False) -> list[dict]:
    """Train and evaluate one run per number of positions; returns the table rows.

    Args:
        dataset: dataset folder (empty-room state 0 is used).
        out: folder for the runs and the table.
        counts: numbers of static positions (train + test, 80/20).
        cfg: training configuration of every run (``max_train_positions`` is set per row).

    Raises:
        ConfigError: the dataset has too few training positions for a row.
    """
    cfg = cfg or TrainConfig()
    data = TrainData.open(dataset, state=cfg.state)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    need = round(0.8 * max(counts))
    if need > len(data.train):
        raise ConfigError(f"motivation table: the largest row needs {need} training positions, dataset {dataset} "
                          f"has {len(data.train)}; generate one with at least {max(counts)} positions")
    rows = []
    for c in counts:
        rc = C.override(cfg, [f"max_train_positions={round(0.8 * c)}"])
        m = _run_and_eval(rc, data, out / f"positions_{c}", quiet=quiet)
        rows.append({"positions": c, **_row(m)})
        _write_table(out, "Test SSIM against the number of static antenna positions", "positions", rows,
                     f"Dataset `{dataset}`; every row is evaluated on the same {m['test_positions']} held-out "
                     f"positions; a row with C positions trains on 0.8*C of them. NN = nearest-neighbour floor "
                     "(from the same training positions).")
    _plot(out / "motivation.png", rows, "positions", "static antenna positions")
    return rows


def knee(counts, ssim) -> int:
    """Index of the knee of an SSIM-against-size curve (Kneedle: with log size and SSIM scaled
    to [0, 1], the point farthest above the chord from the smallest to the largest model).

    Args:
        counts: model sizes (Gaussians), increasing; ssim: the mean SSIM of each.
    Returns:
        the index of the knee (0 when the curve does not rise).
    """
    import numpy as np

    x = np.log(np.maximum(np.asarray(counts, np.float64), 1.0))
    y = np.asarray(ssim, np.float64)
    if len(x) < 3 or np.ptp(x) == 0 or np.ptp(y) == 0 or y[-1] <= y[0]:
        return int(np.argmax(y)) if len(y) else 0
    xn, yn = (x - x[0]) / (x[-1] - x[0]), (y - y[0]) / (y[-1] - y[0])
    return int(np.argmax(yn - xn))


def parsimony_curve(dataset: str | Path, out: str | Path, *, caps=(500, 1000, 2000, 4000, 8000),
                    cfg: TrainConfig | None = None, quiet: bool = False) -> list[dict]:
    """Test SSIM against the number of Gaussians, one run per entry of ``caps``: for the splat
    field a cap on density control (initial Gaussians = min(cap, cfg.field.num_gaussians)); for
    the coherent Gaussian field (``cfg.model == "coherent_gaussians"``) the number of scatterers
    (``scatterers`` and ``room_scatterers``, whichever the room uses).
    The table marks the knee (:func:`knee`)."""
    cfg = cfg or TrainConfig()
    data = TrainData.open(dataset, state=cfg.state)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    coherent = cfg.model == "coherent_gaussians"
    rows, k = [], None
    for cap in caps:
        if coherent:
            rc = C.override(cfg, [f"coherent_gaussians.scatterers={cap}", f"coherent_gaussians.room_scatterers={cap}"])
        else:
            rc = C.override(cfg, [f"density.max_gaussians={cap}",
                                  f"field.num_gaussians={min(cap, cfg.field.num_gaussians)}"])
        m = _run_and_eval(rc, data, out / f"cap_{cap}", quiet=quiet)
        rows.append({"cap": cap, **_row(m)})
        k = knee([r["num_gaussians"] for r in rows], [r["mean"] for r in rows])
        what = "the number of scatterers" if coherent else "the cap of density control"
        _write_table(out, "Parsimony: test SSIM against the number of Gaussians", "cap", rows,
                     f"Dataset `{dataset}`, model {cfg.model}; runs differ only in {what}. Knee (Kneedle on log "
                     f"size): {rows[k]['num_gaussians']} Gaussians, mean SSIM {rows[k]['mean']:.4f}.")
    _plot(out / "parsimony.png", rows, "num_gaussians", "number of Gaussians", knee_index=k)
    return rows


def _plot(path: Path, rows: list[dict], key: str, label: str, *, knee_index: int | None = None) -> None:
    fig, ax = plots.subplots(figsize=(5, 3.5))
    x = [max(r[key], 1) for r in rows]
    ax.plot(x, [r["mean"] for r in rows], "o-", label="model mean")
    ax.plot(x, [r["median"] for r in rows], "s--", label="model median")
    ax.plot(x, [r["nn_mean"] for r in rows], "^:", label="nearest neighbour mean")
    ax.plot(x, [r["idw3_mean"] for r in rows], "v:", label="IDW-3 mean")
    if knee_index is not None:
        ax.plot([x[knee_index]], [rows[knee_index]["mean"]], "r*", markersize=12, label="knee")
    ax.set_xscale("log")
    plots.label(ax, xlabel=label, ylabel="test SSIM", legend_fontsize=8)
    plots.save(fig, path, dpi=110)
