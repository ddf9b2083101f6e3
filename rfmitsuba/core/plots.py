"""Figures for reports and the ``show`` command, drawn without :mod:`matplotlib.pyplot`.

Figures are plain :class:`matplotlib.figure.Figure` objects saved straight to PNG, so
nothing here switches matplotlib's backend or registers figures with pyplot: a notebook
that calls the report functions keeps its inline plots, and no figure is left open.
"""
from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure


def subplots(nrows: int = 1, ncols: int = 1, *, figsize: tuple[float, float], **kw):
    """A new figure and its axes (``Figure.subplots`` arguments: ``squeeze``, ``sharex`` ...)."""
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **kw)


def label(ax, *, xlabel: str, ylabel: str, legend_fontsize: float | None = 8) -> None:
    """Axis labels, a light grid and (unless ``legend_fontsize`` is None) a legend."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    if legend_fontsize is not None:
        ax.legend(fontsize=legend_fontsize)


def save(fig: Figure, path: str | Path, *, dpi: int = 110, tight: bool = True) -> Path:
    """Lay out and write ``fig`` as an image file (format from the suffix); returns the path."""
    if tight:
        fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    return Path(path)


def pas_panel(ax, img, *, title: str, left: bool, bottom: bool, elevation_start_deg: float = 1.0) -> None:
    """One PAS image [90, 360] in a grid of panels: azimuth across, elevation up (row 0 at
    ``elevation_start_deg`` [degrees]), values 0..1; the axis labels on the ``left`` column and
    the ``bottom`` row only."""
    ax.imshow(img, origin="lower", aspect="auto", cmap="viridis", vmin=0, vmax=1,
              extent=(0, 360, elevation_start_deg, elevation_start_deg + 89))
    ax.set_title(title, fontsize=8)
    ax.tick_params(labelsize=6)
    if left:
        ax.set_ylabel("elevation (deg)", fontsize=7)
    if bottom:
        ax.set_xlabel("azimuth (deg)", fontsize=7)
