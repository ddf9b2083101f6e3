"""Figures of an evaluation: the PAS grid (ground truth, prediction, nearest neighbour from
worst to best), the SSIM CDF, validation SSIM against training wall time, and the map of where
the model breaks (per test position, seen from above).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..core import plots


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
            plots.pas_panel(axes[r, c], img, title=title, left=c == 0, bottom=r == len(pick) - 1)
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


def plot_map(path: Path, test_pos: np.ndarray, train_pos: np.ndarray, s_model: np.ndarray, s_floor: np.ndarray, *,
             fixed: np.ndarray | None = None) -> None:
    """Two top views (x, y [m]) of the test positions: the model's SSIM, and its margin over the best
    neighbour floor (``s_model - s_floor``, red where the floor wins); training positions grey,
    the fixed device a star.

    Args:
        test_pos: float [K, 3] m; train_pos: float [M, 3] m; s_model, s_floor: float [K];
        fixed: float [3] m or None.
    """
    margin = np.asarray(s_model) - np.asarray(s_floor)
    lim = max(float(np.abs(margin).max()), 1e-3)
    fig, axes = plots.subplots(1, 2, figsize=(11, 4.4), squeeze=False)
    for ax, values, title, kw in (
            (axes[0, 0], s_model, "model SSIM", {"cmap": "viridis", "vmin": float(np.min(s_model)), "vmax": 1.0}),
            (axes[0, 1], margin, "model minus best neighbour floor", {"cmap": "RdBu", "vmin": -lim, "vmax": lim})):
        ax.scatter(train_pos[:, 0], train_pos[:, 1], s=2, c="0.8", label="training positions")
        sc = ax.scatter(test_pos[:, 0], test_pos[:, 1], s=14, c=values, edgecolors="none", **kw)
        if fixed is not None:
            ax.plot([fixed[0]], [fixed[1]], "k*", ms=12, label="fixed device")
        fig.colorbar(sc, ax=ax, shrink=0.85)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(title, fontsize=9)
        plots.label(ax, xlabel="x (m)", ylabel="y (m)", legend_fontsize=7)
    plots.save(fig, path, dpi=110)
