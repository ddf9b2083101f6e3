"""Stage-1 experiments made of several runs: the motivation table, the parsimony curve and the
split sensitivity.

* :func:`motivation_table` - test SSIM against the number of static antenna positions
  (paper, Table "motivation": 900, 1500, 3600, 6000, 10000 positions). A row with C positions
  trains on ``round(0.8 * C)`` positions drawn from the dataset's training split (the 80/20 rule
  of docs/conventions.md) and is evaluated on the dataset's whole test split, the same for every row, so rows
  are comparable. The dataset must hold enough training positions for the largest row.
* :func:`parsimony_curve` - test SSIM against the number of Gaussians ("a model no larger than
  the scene needs"): splat runs whose density control is capped at different sizes, or coherent
  Gaussian runs with different numbers of scatterers; :func:`knee` picks the knee of the curve.
* :func:`split_sensitivity` - every field and floor under the dataset's own split and the
  spatial-block split: how much of a score is interpolation (SPEC, "Splits").

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
from ..train.trainer import Trainer, train

MOTIVATION_COUNTS = (900, 1500, 3600, 6000, 10000)
QUICK_MOTIVATION_COUNTS = (150, 300, 600, 900)


def _one_kind(cfg: TrainConfig, table: str) -> None:
    if cfg.model == "auto":
        raise ConfigError(f"the {table} table compares one field kind across its rows: set model (e.g. 'splat' or "
                          "'coherent_gaussians'), not 'auto'")


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
        ConfigError: the dataset has too few training positions for a row, or ``cfg.model`` is
        "auto" (the table compares one field kind across counts).
    """
    cfg = cfg or TrainConfig(model="splat")
    _one_kind(cfg, "motivation")
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
    field a cap on density control (initial Gaussians = min(cap, cfg.splat.num_gaussians)); for
    the coherent Gaussian field (``cfg.model == "coherent_gaussians"``) the number of scatterers
    (``scatterers`` and ``room_scatterers``, whichever the room uses).
    The table marks the knee (:func:`knee`)."""
    cfg = cfg or TrainConfig(model="splat")
    _one_kind(cfg, "parsimony")
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
                                  f"splat.num_gaussians={min(cap, cfg.splat.num_gaussians)}"])
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


#: the two splits of :func:`split_sensitivity`: the dataset's own (a NeRF2 folder's published
#: random index files) and the held-out slab of the largest x (SPEC, "Splits")
SENSITIVITY_SPLITS = ("dataset", "block")
#: fields of :func:`split_sensitivity` by default: the coherent Gaussian field and the paper's splat field
SENSITIVITY_FIELDS = ("coherent_gaussians", "splat")


def _mean_std(xs) -> tuple[float, float]:
    """Mean and sample standard deviation (ddof 1, as :func:`rfmitsuba.experiments.results.mean_std_n`;
    0 for one seed)."""
    import numpy as np

    a = np.asarray(xs, np.float64)
    return float(a.mean()), (float(a.std(ddof=1)) if len(a) > 1 else 0.0)


def split_sensitivity(dataset: str | Path, out: str | Path, *, fields=SENSITIVITY_FIELDS, seeds=(0, 1, 2),
                      cfg: TrainConfig | None = None, tag: str = "", quiet: bool = False) -> list[dict]:
    """How much of a score is interpolation: every field and every floor under the dataset's own
    split and the spatial-block split (SPEC, "Splits": measured data, always both).

    One run per field x split x seed (``OUT/<field>_<split>_s<seed>``, or
    ``OUT/<field>-<tag>_<split>_s<seed>`` with a ``tag``; an ordinary run folder: a killed
    experiment resumes, finished runs are not trained or evaluated again). The table also shows
    the runs of other fields or tags already in ``OUT``, so a field that needs other settings
    (fewer splat steps) can be added by a second call into the same folder, and one field under
    other settings (``iterations = 12000``) by a second call with a tag naming them; a finished run of
    another configuration under the same name is refused, not reused. A field is a
    ``model`` kind (``"auto"`` included: what ``rfmitsuba train`` picks). The table
    (``OUT/table.md``, ``OUT/table.json``) gives per field and split the model's and the
    neighbour-anchored prediction's mean / median test SSIM (mean and std over seeds), the
    nearest-neighbour, IDW-3 and mean-image floors of the same split, how many seeds beat the best
    floor in mean and median, size and training time; then the drop from the dataset's split to
    the block split, for each field and floor. ``OUT/splits.png`` draws it.

    Args:
        dataset: dataset folder (rfmitsuba or NeRF2 layout).
        out: folder for the runs and the table.
        fields: model kinds, one row each per split.
        seeds: training seeds (the block split is the same for every seed; the dataset's is its own).
        cfg: training configuration of every run (``model``, ``split`` and ``seed`` are set per run).
        tag: a name for these settings in the table's rows and the run folders (letters, digits
            and ``.=+``; "" = the field alone).
    Returns:
        the table rows (one per field and split).
    Raises:
        ConfigError: no fields or no seeds, a field that is not a Stage-1 kind, or a bad tag.
        RunError: a finished run in ``OUT`` under a requested name holds another configuration.
    """
    import re

    fields, seeds = tuple(fields), tuple(int(s) for s in seeds)
    if not fields or not seeds:
        raise ConfigError("split sensitivity needs at least one field and one seed")
    if tag and not re.fullmatch(r"[A-Za-z0-9.=+]+", tag):
        raise ConfigError(f"split sensitivity: tag {tag!r} may hold letters, digits and '.=+' only")
    cfg = cfg or TrainConfig()
    for f in fields:  # every field is a Stage-1 kind (ConfigError naming the known ones) before any run starts
        C.override(cfg, [f'model="{f}"'])
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = [f"{f}-{tag}" if tag else f for f in fields]
    for split in SENSITIVITY_SPLITS:
        for f, name in zip(fields, names):
            for s in seeds:
                rd = out / f"{name}_{split}_s{s}"
                # a finished run returns at once; one of another configuration is refused by the trainer
                train(dataset, rd, cfg=C.override(cfg, [f'model="{f}"', f'split="{split}"', f"seed={s}"]), quiet=quiet)
                if not (rd / "eval" / "metrics.json").is_file():
                    evaluate_run(rd)
            rows = _sensitivity_rows(out, names)      # the table grows field by field
            _write_sensitivity(out, dataset, rows)
    _plot_sensitivity(out / "splits.png", rows)
    return rows


def _sensitivity_rows(out: Path, fields) -> list[dict]:
    """One row per field and split from the evaluated runs in ``out``: ``fields`` first, then any
    other field found there (an earlier call with other fields or settings into the same folder)."""
    import re

    found: dict[tuple[str, str], list[dict]] = {}
    for rd in sorted(out.iterdir()):
        m = re.fullmatch(r"(.+)_(" + "|".join(SENSITIVITY_SPLITS) + r")_s(\d+)", rd.name)
        if m and (rd / "eval" / "metrics.json").is_file():
            found.setdefault((m.group(1), m.group(2)), []).append(json.loads((rd / "eval" / "metrics.json").read_text()))
    order = list(fields) + sorted({f for f, _ in found} - set(fields))
    return [_sensitivity_row(f, split, found[f, split]) for split in SENSITIVITY_SPLITS for f in order
            if (f, split) in found]


def _sensitivity_row(field: str, split: str, ms: list[dict]) -> dict:
    def both(key):
        return {"mean": _mean_std([m[key]["mean"] for m in ms]), "median": _mean_std([m[key]["median"] for m in ms])}

    anch = [m.get("anchored", {}).get("test") or m["model"] for m in ms]
    return {"field": field, "split": split, "seeds": len(ms), "model": both("model"),
            "anchored": {"mean": _mean_std([a["mean"] for a in anch]), "median": _mean_std([a["median"] for a in anch])},
            "nearest_neighbour": both("nearest_neighbour"), "idw3": both("idw3"), "mean_image": both("mean_image"),
            "beats_best_floor": sum(bool(m["beats_best_floor"]) for m in ms),
            "anchored_beats_best_floor": sum(bool(m.get("anchored", m)["beats_best_floor"]) for m in ms),
            "num_gaussians": sorted({int(m["num_gaussians"]) for m in ms}),
            "num_parameters": sorted({int(m["num_parameters"]) for m in ms}),
            "train_steps": ms[0].get("train_steps"), "train_time_s": _mean_std([m["train_time_s"] for m in ms]),
            "test_positions": ms[0]["test_positions"], "train_positions": ms[0]["train_positions"],
            "runs": [m["run"] for m in ms]}


def _ms(v: tuple[float, float], n: int) -> str:
    return f"{v[0]:.3f} ± {v[1]:.3f}" if n > 1 else f"{v[0]:.3f}"


def _span(values: list[int]) -> str:
    """One size, or the range over seeds (``auto`` may choose another field per seed)."""
    return str(values[0]) if len(values) == 1 else f"{values[0]}–{values[-1]}"


def _write_sensitivity(out: Path, dataset, rows: list[dict]) -> None:
    lines = ["# Split sensitivity: how much of a score is interpolation", "",
             f"Dataset `{dataset}`. Every field and floor under the dataset's own split (a NeRF2 folder's published "
             "index files: random, test tags millimetres from training ones) and the spatial-block split (the 20% "
             "of positions with the largest x held out as a slab; SPEC, \"Splits\"). Mean ± sample std over seeds; "
             "*anchored* is eval's neighbour-anchored prediction (`rfmitsuba.eval.anchor`), chosen on validation; "
             "*beats* counts the seeds that beat the best floor (NN or IDW-3) in mean and median (model / anchored).",
             "", "| split | field | seeds | model mean / median | anchored mean / median | beats | NN mean / median | "
                 "IDW-3 mean / median | mean image | Gaussians | parameters | steps | train s |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        n = r["seeds"]
        lines.append(
            f"| {r['split']} ({r['train_positions']}/{r['test_positions']}) | {r['field']} | {n} | "
            f"{_ms(r['model']['mean'], n)} / {_ms(r['model']['median'], n)} | "
            f"{_ms(r['anchored']['mean'], n)} / {_ms(r['anchored']['median'], n)} | "
            f"{r['beats_best_floor']}/{n} / {r['anchored_beats_best_floor']}/{n} | "
            f"{r['nearest_neighbour']['mean'][0]:.3f} / {r['nearest_neighbour']['median'][0]:.3f} | "
            f"{r['idw3']['mean'][0]:.3f} / {r['idw3']['median'][0]:.3f} | {r['mean_image']['mean'][0]:.3f} | "
            f"{_span(r['num_gaussians'])} | {_span(r['num_parameters'])} | {r['train_steps']} | {r['train_time_s'][0]:.0f} |")
    by = {(r["field"], r["split"]): r for r in rows}
    fields = list(dict.fromkeys(r["field"] for r in rows))
    a, b = SENSITIVITY_SPLITS
    drops = []
    for f in fields:
        if (f, a) in by and (f, b) in by:
            drops.append((f, by[f, a]["model"]["mean"][0] - by[f, b]["model"]["mean"][0],
                          by[f, a]["anchored"]["mean"][0] - by[f, b]["anchored"]["mean"][0]))
    if drops:
        r0, r1 = by[drops[0][0], a], by[drops[0][0], b]
        lines += ["", f"Drop in mean SSIM from the {a} split to the {b} split (what interpolation was worth):", "",
                  "| what | drop |", "|---|---|"]
        lines += [f"| {f} (model / anchored) | {d:+.3f} / {da:+.3f} |" for f, d, da in drops]
        lines += [f"| {name} | {r0[k]['mean'][0] - r1[k]['mean'][0]:+.3f} |"
                  for k, name in (("nearest_neighbour", "nearest neighbour"), ("idw3", "IDW-3"),
                                  ("mean_image", "mean image"))]
    (out / "table.md").write_text("\n".join(lines) + "\n")
    (out / "table.json").write_text(json.dumps(rows, indent=1))


def _plot_sensitivity(path: Path, rows: list[dict]) -> None:
    import numpy as np

    fields = list(dict.fromkeys(r["field"] for r in rows))
    names = list(fields) + ["nearest neighbour", "IDW-3", "mean image"]
    fig, ax = plots.subplots(figsize=(1.2 * len(names) + 2.5, 3.6))
    width = 0.8 / len(SENSITIVITY_SPLITS)
    for j, split in enumerate(SENSITIVITY_SPLITS):
        rs = {r["field"]: r for r in rows if r["split"] == split}
        if not rs:
            continue
        any_r = next(iter(rs.values()))
        vals = [rs[f]["model"]["mean"] if f in rs else (np.nan, 0.0) for f in fields]
        vals += [any_r[k]["mean"] for k in ("nearest_neighbour", "idw3", "mean_image")]
        x = np.arange(len(names)) + (j - (len(SENSITIVITY_SPLITS) - 1) / 2) * width
        ax.bar(x, [v[0] for v in vals], width, yerr=[v[1] for v in vals], capsize=2,
               label=f"{split} split ({any_r['train_positions']}/{any_r['test_positions']})")
    ax.set_xticks(np.arange(len(names)))
    ax.set_xticklabels(names, rotation=20, ha="right", fontsize=8)
    lo = min((r[k]["mean"][0] for r in rows for k in ("model", "mean_image")), default=0.0)
    ax.set_ylim(max(0.0, lo - 0.05), 1.0)
    plots.label(ax, xlabel="", ylabel="test mean SSIM", legend_fontsize=8)
    plots.save(fig, path, dpi=110)
