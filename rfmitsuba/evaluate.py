"""Evaluation by the SPEC metric protocol, model-free floors, and the run report.

Protocol (SPEC "Metric protocol"): every predicted and ground-truth PAS is min-max
normalised on its own, compared with ``skimage.metrics.structural_similarity(pred, gt,
data_range=1.0)`` (7x7 uniform window), per image; mean and median over the test set.
Two floors on the same split: **nearest neighbour** (the training PAS whose antenna
position - and human position, where given - is nearest) and **mean image** (the mean of the
normalised training PAS). Wall times of training and rendering are reported too.

:func:`evaluate_run` writes ``RUN/eval/``: ``summary.md``, ``metrics.json``, ``ssim.npz``
(per-image SSIM of model and floors) and the plots ``grid.png`` (ground truth, prediction,
nearest neighbour at test positions from worst to best), ``ssim_cdf.png`` and
``ssim_vs_time.png`` (validation SSIM during training against wall time).
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from . import plots
from .errors import RunError
from .train import minmax


def ssim_images(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """SSIM per image pair (skimage, data_range=1, default 7x7 window).

    Args:
        pred, gt: float [K, H, W], already min-max normalised to [0, 1].

    Returns:
        float64 [K].
    """
    from skimage.metrics import structural_similarity

    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if pred.shape != gt.shape or pred.ndim != 3:
        raise ValueError(f"ssim_images: pred {pred.shape} and gt {gt.shape} must both be [K, H, W]")
    return np.array([structural_similarity(p, g, data_range=1.0) for p, g in zip(pred, gt)], dtype=np.float64)


def nearest_index(train_pos: np.ndarray, query_pos: np.ndarray, *, train_human: np.ndarray | None = None,
                  query_human: np.ndarray | None = None) -> np.ndarray:
    """Index of the nearest training sample for every query.

    Distance: Euclidean over the antenna position (metres), plus the human position
    where both are given (6-D distance; NaN human rows, i.e. empty room, count as a human
    far away from any real position).

    Args:
        train_pos: float [M, 3] metres; query_pos: float [K, 3] metres.
        train_human / query_human: float [M, 3] / [K, 3] metres or None.

    Returns:
        int64 [K] indices into the training rows (ties: the lowest index).
    """
    from scipy.spatial import cKDTree

    a = np.asarray(train_pos, np.float64)
    q = np.asarray(query_pos, np.float64)
    if train_human is not None and query_human is not None:
        th = np.nan_to_num(np.asarray(train_human, np.float64), nan=1e3)
        qh = np.nan_to_num(np.asarray(query_human, np.float64), nan=1e3)
        a, q = np.concatenate([a, th], 1), np.concatenate([q, qh], 1)
    if len(a) == 0:
        raise ValueError("nearest_index: no training samples")
    _, idx = cKDTree(a).query(q, k=1)
    return np.asarray(idx, dtype=np.int64)


def floors(train_pas: np.ndarray, train_pos: np.ndarray, test_pas: np.ndarray, test_pos: np.ndarray, *,
           train_human=None, test_human=None) -> dict:
    """Model-free baselines on one split.

    Args:
        train_pas: float [M, H, W] normalised training PAS; train_pos: float [M, 3] metres.
        test_pas: float [K, H, W] normalised test PAS; test_pos: float [K, 3] metres.
        train_human / test_human: optional human positions [M, 3] / [K, 3].

    Returns:
        {"nearest_neighbour": float64 [K] SSIM, "nearest_index": int64 [K],
         "mean_image": float64 [K] SSIM}.
    """
    idx = nearest_index(train_pos, test_pos, train_human=train_human, query_human=test_human)
    nn_pred = np.asarray(train_pas)[idx]
    mean_img = minmax(np.asarray(train_pas, np.float64).mean(axis=0)[None])
    return {"nearest_neighbour": ssim_images(nn_pred, test_pas), "nearest_index": idx,
            "mean_image": ssim_images(np.repeat(mean_img, len(test_pas), axis=0), test_pas)}


def stats(x: np.ndarray) -> dict:
    """Mean, median, 10th percentile, min of per-image SSIM."""
    x = np.asarray(x, np.float64)
    return {"mean": float(x.mean()), "median": float(np.median(x)), "p10": float(np.percentile(x, 10)),
            "min": float(x.min()), "n": int(len(x))}


def evaluate_run(run_dir: str | Path, *, batch: int = 8, quiet: bool = False) -> dict:
    """Evaluate a finished run on its test split (full 90 x 360 resolution) and write ``RUN/eval``.

    Returns:
        the metrics dict (also ``RUN/eval/metrics.json``).

    Raises:
        RunError: not a run folder, or training not finished.
    """
    from .train import load_run

    rd = Path(run_dir)
    cfg, data, field, tr = load_run(rd)
    split = json.loads((rd / "split.json").read_text())
    train_idx = np.asarray(split["train"], np.int64)
    test_idx = np.asarray(split["test"], np.int64)
    gt_test = data.pas(test_idx)
    t0 = time.perf_counter()
    pred = tr.predict(field, test_idx, h=90, w=360, batch=batch)
    render_s = time.perf_counter() - t0
    if not np.isfinite(pred).all():
        raise RunError(f"{rd}: the model renders non-finite values")
    model_ssim = ssim_images(minmax(pred), gt_test)
    gt_train = data.pas(train_idx)
    fl = floors(gt_train, data.antenna_pos[train_idx], gt_test, data.antenna_pos[test_idx])
    summary = json.loads((rd / "final" / "summary.json").read_text())
    metrics = {
        "run": str(rd), "dataset": str(data.path), "task": data.task, "test_positions": int(len(test_idx)),
        "train_positions": int(len(train_idx)),
        "model": stats(model_ssim), "nearest_neighbour": stats(fl["nearest_neighbour"]),
        "mean_image": stats(fl["mean_image"]),
        "beats_nearest_neighbour": bool(model_ssim.mean() > fl["nearest_neighbour"].mean()),
        "num_gaussians": field.num_gaussians, "num_parameters": field.num_parameters,
        "network_parameters": field.network_parameters,
        "train_time_s": summary.get("train_time_s"), "train_steps": summary.get("steps"),
        "render_time_s": render_s, "render_ms_per_image": 1000 * render_s / max(len(test_idx), 1),
        "load_average_1min": os.getloadavg()[0], "cpu_count": os.cpu_count(),
    }
    out = rd / "eval"
    out.mkdir(exist_ok=True)
    np.savez(out / "ssim.npz", model=model_ssim, nearest_neighbour=fl["nearest_neighbour"],
             mean_image=fl["mean_image"], test_index=test_idx)
    (out / "metrics.json").write_text(json.dumps(metrics, indent=1))
    (out / "summary.md").write_text(summary_markdown(metrics))
    plot_grid(out / "grid.png", gt_test, minmax(pred), gt_train[fl["nearest_index"]], model_ssim,
              fl["nearest_neighbour"])
    plot_cdf(out / "ssim_cdf.png", {"model": model_ssim, "nearest neighbour": fl["nearest_neighbour"],
                                    "mean image": fl["mean_image"]})
    plot_time(out / "ssim_vs_time.png", rd / "log.jsonl", final=(metrics["train_time_s"], metrics["model"]["mean"]))
    return metrics


def summary_markdown(m: dict) -> str:
    """The Markdown report of :func:`evaluate_run`'s metrics."""
    verdict = ("The model beats the nearest-neighbour floor (mean SSIM)." if m["beats_nearest_neighbour"] else
               "The model does NOT beat the nearest-neighbour floor (mean SSIM): on average it has learned "
               "nothing more useful than a lookup of the closest training PAS.")
    rows = [("model", m["model"]), ("nearest neighbour", m["nearest_neighbour"]), ("mean image", m["mean_image"])]
    lines = [
        f"# Evaluation of `{m['run']}`", "",
        f"Dataset `{m['dataset']}`, task moving-{m['task'].upper()}, {m['train_positions']} training and "
        f"{m['test_positions']} held-out test positions. SSIM by the SPEC protocol (skimage, data_range=1, "
        "7x7 window, per-image min-max normalised 90x360 PAS).", "",
        "| method | mean SSIM | median SSIM | 10th pct | min |", "|---|---|---|---|---|",
    ]
    lines += [f"| {name} | {s['mean']:.4f} | {s['median']:.4f} | {s['p10']:.4f} | {s['min']:.4f} |" for name, s in rows]
    lines += ["", verdict, "",
              f"- Gaussians: {m['num_gaussians']}; parameters: {m['num_parameters']} "
              f"(network {m['network_parameters']})",
              f"- training: {m['train_steps']} steps, {m['train_time_s']:.1f} s wall time",
              f"- rendering: {m['render_time_s']:.2f} s for {m['test_positions']} images "
              f"({m['render_ms_per_image']:.1f} ms per image); machine: {m['cpu_count']} cores, "
              f"1-minute load average {m['load_average_1min']:.1f} at evaluation (shared machines time slower)", "",
              "Plots: `grid.png` (ground truth / prediction / nearest neighbour), `ssim_cdf.png`, "
              "`ssim_vs_time.png`.", ""]
    return "\n".join(lines)


# --------------------------------------------------------------------------- plots

def plot_grid(path: Path, gt: np.ndarray, pred: np.ndarray, nn: np.ndarray, s_model: np.ndarray,
              s_nn: np.ndarray, *, count: int = 6) -> None:
    """Ground truth, prediction and nearest neighbour at ``count`` test positions spread from the
    worst to the best model SSIM."""
    order = np.argsort(s_model)
    pick = order[np.linspace(0, len(order) - 1, min(count, len(order))).astype(int)]
    fig, axes = plots.subplots(len(pick), 3, figsize=(12, 1.6 * len(pick) + 0.6), squeeze=False)
    for r, i in enumerate(pick):
        for c, (img, title) in enumerate([(gt[i], "ground truth"), (pred[i], f"model SSIM {s_model[i]:.3f}"),
                                          (nn[i], f"nearest neighbour SSIM {s_nn[i]:.3f}")]):
            ax = axes[r, c]
            ax.imshow(img, origin="lower", aspect="auto", extent=(0, 360, 1, 90), vmin=0, vmax=1, cmap="viridis")
            ax.set_title(title, fontsize=8)
            ax.tick_params(labelsize=6)
            if c == 0:
                ax.set_ylabel("elevation (deg)", fontsize=7)
            if r == len(pick) - 1:
                ax.set_xlabel("azimuth (deg)", fontsize=7)
    plots.save(fig, path, dpi=110)


def plot_cdf(path: Path, series: dict) -> None:
    """Empirical CDF of per-image SSIM for each named series."""
    fig, ax = plots.subplots(figsize=(5, 3.5))
    for name, x in series.items():
        x = np.sort(np.asarray(x))
        ax.plot(x, np.arange(1, len(x) + 1) / len(x), label=f"{name} (mean {x.mean():.3f})")
    plots.label(ax, xlabel="SSIM", ylabel="fraction of test images", legend_fontsize=8)
    plots.save(fig, path, dpi=110)


def plot_time(path: Path, log_file: Path, *, final: tuple | None = None) -> None:
    """Validation SSIM against training wall time (from ``log.jsonl``), with the final test mean."""
    rows = [json.loads(ln) for ln in log_file.read_text().splitlines() if ln.strip()] if log_file.is_file() else []
    rows = [r for r in rows if "val_ssim" in r]
    fig, ax = plots.subplots(figsize=(5, 3.5))
    if rows:
        ax.plot([r["time_s"] for r in rows], [r["val_ssim"] for r in rows], "o-", ms=3, label="validation SSIM")
    if final and final[0] is not None:
        ax.plot([final[0]], [final[1]], "r*", ms=10, label="test mean SSIM")
    plots.label(ax, xlabel="training wall time (s)", ylabel="mean SSIM", legend_fontsize=8)
    plots.save(fig, path, dpi=110)
