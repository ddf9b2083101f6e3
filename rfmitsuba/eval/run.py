"""Evaluation of one Stage-1 run folder on its test split, by the metric protocol of
:mod:`rfmitsuba.core.ssim`, with the three floors: nearest neighbour, IDW-3 and mean image.

:func:`evaluate_run` writes ``RUN/eval/``: ``summary.md``, ``metrics.json``, ``ssim.npz``
(per-image SSIM of model and floors) and the plots ``grid.png`` (ground truth, prediction,
nearest neighbour at test positions from worst to best), ``ssim_cdf.png``,
``ssim_vs_time.png`` (validation SSIM during training against wall time) and ``ssim_map.png``
(where the model breaks: per test position, its SSIM and its margin over the best neighbour
floor, seen from above). The metrics also hold the model's fit at its own training positions
(the generalisation gap) and its SSIM by distance to the fixed device and to the nearest
training position (:mod:`rfmitsuba.eval.breakdown`).
"""
from __future__ import annotations

import json
import os
import time
import warnings
from pathlib import Path

import numpy as np

from ..core.errors import RunError
from ..core.ssim import ssim_images
from ..rf.bartlett_ref import normalize as minmax
from ..train.trainer import load_run
from .anchor import anchored, choose
from .breakdown import DISTANCES, breakdown, fixed_device
from .dynamic_static import fit_rows
from .figures import plot_cdf, plot_grid, plot_map, plot_time
from .metrics import best_floor, floors, stats


def evaluate_run(run_dir: str | Path, *, batch: int = 8, quiet: bool = False) -> dict:
    """Evaluate a finished run on its test split (full 90 x 360 resolution) and write ``RUN/eval``.

    Returns:
        the metrics dict (also ``RUN/eval/metrics.json``).

    Raises:
        RunError: not a run folder, or training not finished.
    """

    rd = Path(run_dir)
    with warnings.catch_warnings(record=True) as caught:   # e.g. the dataset changed since training
        warnings.simplefilter("always")
        cfg, data, renderer = load_run(rd)
    opened = [str(w.message) for w in caught]
    for w in caught:   # still shown where they arise; also kept in the report below
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    fields = renderer.fields
    split = json.loads((rd / "split.json").read_text())
    train_idx = np.asarray(split["train"], np.int64)
    test_idx = np.asarray(split["test"], np.int64)
    gt_test = data.pas(test_idx)
    t0 = time.perf_counter()
    pred = renderer.render(data, test_idx, batch=batch)
    render_s = time.perf_counter() - t0
    if not np.isfinite(pred).all():
        raise RunError(f"{rd}: the model renders non-finite values")
    model_ssim = ssim_images(minmax(pred), gt_test)
    gt_train = data.pas(train_idx)
    pos = data.antenna_pos
    fl = floors(gt_train, pos[train_idx], gt_test, pos[test_idx])
    # the neighbour-anchored prediction (rfmitsuba.eval.anchor): (k, alpha) chosen on the
    # validation positions with anchors from the fitting ones, then applied with every training one
    val_idx = np.asarray(split.get("val", []), np.int64)
    fit_idx = np.asarray(split.get("fit", []), np.int64)
    anchor = None
    field_train = None
    if len(val_idx) and len(fit_idx):
        field_train = minmax(renderer.render(data, train_idx, batch=batch))
        at = {int(i): n for n, i in enumerate(train_idx)}
        rows_fit, rows_val = [at[int(i)] for i in fit_idx], [at[int(i)] for i in val_idx]
        choice = choose(field_train[rows_val], field_train[rows_fit], gt_train[rows_fit], pos[fit_idx],
                        pos[val_idx], gt_train[rows_val])
        anchored_ssim = model_ssim if choice["use"] == "field" else ssim_images(
            anchored(minmax(pred), field_train, gt_train, pos[train_idx], pos[test_idx], k=choice["k"],
                     alpha=choice["alpha"]), gt_test)
        anchor = {**choice, "test": stats(anchored_ssim)}
    rows = fit_rows(len(train_idx))   # the model at its own training positions
    fit_pred = field_train[rows] if field_train is not None else minmax(
        renderer.render(data, train_idx[rows], batch=batch))
    fit_ssim = ssim_images(fit_pred, gt_train[rows])
    fixed = fixed_device(data)
    summary = json.loads((rd / "final" / "summary.json").read_text())
    metrics = {
        "run": str(rd), "dataset": str(data.path), "task": data.task, "test_positions": int(len(test_idx)),
        "warnings": opened,
        "train_positions": int(len(train_idx)),
        "model": stats(model_ssim), "fit": stats(fit_ssim), "nearest_neighbour": stats(fl["nearest_neighbour"]),
        "idw3": stats(fl["idw3"]), "mean_image": stats(fl["mean_image"]),
        "beats_nearest_neighbour": bool(model_ssim.mean() > fl["nearest_neighbour"].mean()),
        "split": cfg.split,
        "num_gaussians": sum(f.num_primitives for f in fields),
        "num_parameters": sum(f.num_parameters for f in fields),
        "network_parameters": sum(f.network_parameters for f in fields),
        "train_time_s": summary.get("train_time_s"), "train_steps": summary.get("steps"),
        "render_time_s": render_s, "render_ms_per_image": 1000 * render_s / max(len(test_idx), 1),
        "load_average_1min": os.getloadavg()[0], "cpu_count": os.cpu_count(),
        "by_distance": breakdown(pos[test_idx], pos[train_idx], fixed,
                                 {"model": model_ssim, "nearest_neighbour": fl["nearest_neighbour"],
                                  "idw3": fl["idw3"]}),
    }
    best, best_stats = best_floor(metrics)
    metrics["best_floor"] = best
    metrics["beats_best_floor"] = bool(metrics["model"]["mean"] > best_stats["mean"]
                                       and metrics["model"]["median"] > best_stats["median"])
    if anchor is not None:
        anchor["beats_best_floor"] = bool(anchor["test"]["mean"] > best_stats["mean"]
                                          and anchor["test"]["median"] > best_stats["median"])
        metrics["anchored"] = anchor
    out = rd / "eval"
    out.mkdir(exist_ok=True)
    np.savez(out / "ssim.npz", model=model_ssim, nearest_neighbour=fl["nearest_neighbour"],
             idw3=fl["idw3"], mean_image=fl["mean_image"], test_index=test_idx)
    (out / "metrics.json").write_text(json.dumps(metrics, indent=1))
    (out / "summary.md").write_text(summary_markdown(metrics))
    plot_grid(out / "grid.png", gt_test, minmax(pred), gt_train[fl["nearest_index"]], model_ssim,
              fl["nearest_neighbour"])
    plot_cdf(out / "ssim_cdf.png", {"model": model_ssim, "nearest neighbour": fl["nearest_neighbour"],
                                    "IDW-3": fl["idw3"], "mean image": fl["mean_image"]})
    plot_time(out / "ssim_vs_time.png", rd / "log.jsonl", final=(metrics["train_time_s"], metrics["model"]["mean"]))
    plot_map(out / "ssim_map.png", pos[test_idx], pos[train_idx], model_ssim,
             np.maximum(fl["nearest_neighbour"], fl["idw3"]), fixed=fixed)
    return metrics


def summary_markdown(m: dict) -> str:
    """The Markdown report of :func:`evaluate_run`'s metrics."""
    names = {"nearest_neighbour": "nearest neighbour", "idw3": "IDW-3"}
    best = names[m.get("best_floor", "nearest_neighbour")]
    verdict = (f"The model beats the best neighbour floor ({best}) in mean and median SSIM."
               if m.get("beats_best_floor") else
               f"The model does NOT beat the best neighbour floor ({best}) in both mean and median SSIM: "
               "it has learned nothing more useful than a lookup of the closest training PAS.")
    rows = [("model", m["model"])]
    a = m.get("anchored")
    if a:
        how = "the model alone" if a["use"] == "field" else f"k = {a['k']}, alpha = {a['alpha']:g}"
        rows += [(f"model or model + neighbour anchor, chosen on validation ({how})", a["test"])]
    rows += [("nearest neighbour", m["nearest_neighbour"])]
    rows += [("IDW-3", m["idw3"])] if m.get("idw3") else []
    rows += [("mean image", m["mean_image"])]
    lines = [
        f"# Evaluation of `{m['run']}`", "",
        f"Dataset `{m['dataset']}`, task moving-{m['task'].upper()}, {m['train_positions']} training and "
        f"{m['test_positions']} held-out test positions (split: {m.get('split', 'dataset')}). SSIM by the metric protocol (docs/conventions.md) (skimage, data_range=1, "
        "7x7 window, per-image min-max normalised 90x360 PAS).", "",
        "| method | mean SSIM | median SSIM | 10th pct | min |", "|---|---|---|---|---|",
    ]
    lines += [f"| {name} | {s['mean']:.4f} | {s['median']:.4f} | {s['p10']:.4f} | {s['min']:.4f} |" for name, s in rows]
    if m.get("fit"):
        f = m["fit"]
        lines += ["", f"At {f['n']} of its own training positions the model scores {f['mean']:.4f} mean SSIM "
                  f"(test {m['model']['mean']:.4f}: a generalisation gap of {f['mean'] - m['model']['mean']:+.4f})."]
    lines += _breakdown_lines(m.get("by_distance"))
    if a:
        lines += ["", "The neighbour-anchored prediction (`rfmitsuba.eval.anchor`) adds the model's change from the "
                  "nearest training positions to their measured spectra; it or the model alone, and its (k, alpha), "
                  f"were chosen on the validation positions (validation SSIM {a['val_ssim']:.4f}, the model alone "
                  f"{a['field_val_ssim']:.4f}); it "
                  + ("beats" if a["beats_best_floor"] else "does NOT beat") + f" the best floor ({best}) in mean "
                  "and median."]
    lines += [f"- **Warning:** {w}" for w in m.get("warnings", [])]
    lines += ["", verdict, "",
              f"- Gaussians: {m['num_gaussians']}; parameters: {m['num_parameters']} "
              f"(network {m['network_parameters']})",
              f"- training: {m['train_steps']} steps, {m['train_time_s']:.1f} s wall time",
              f"- rendering: {m['render_time_s']:.2f} s for {m['test_positions']} images "
              f"({m['render_ms_per_image']:.1f} ms per image); machine: {m['cpu_count']} cores, "
              f"1-minute load average {m['load_average_1min']:.1f} at evaluation (shared machines time slower)", "",
              "Plots: `grid.png` (ground truth / prediction / nearest neighbour), `ssim_cdf.png`, "
              "`ssim_vs_time.png`, `ssim_map.png` (per test position: SSIM and margin over the best neighbour "
              "floor, from above).", ""]
    return "\n".join(lines)


def _breakdown_lines(b: dict | None) -> list[str]:
    """Markdown table of :func:`rfmitsuba.eval.breakdown.breakdown`: mean SSIM of the model, nearest
    neighbour and IDW-3 per quartile of each distance."""
    if not b:
        return []
    out = ["", "Where the model breaks: mean SSIM per quartile of a distance (model / nearest neighbour / IDW-3).", "",
           "| distance | quartile (m) | images | model | nearest neighbour | IDW-3 |", "|---|---|---|---|---|---|"]
    for key, name in DISTANCES.items():
        part = b.get(key)
        if not part:
            continue
        for i, (lo, hi) in enumerate(zip(part["edges"][:-1], part["edges"][1:])):
            out.append(f"| {name} | {lo:.3f}–{hi:.3f} | {part['count'][i]} | {part['model'][i]:.4f} | "
                       f"{part['nearest_neighbour'][i]:.4f} | {part['idw3'][i]:.4f} |")
    return out
