"""Speed against accuracy during training: validation SSIM against training wall time, every method.

The trainer validates every ``val_every`` steps and logs ``{step, val_ssim, time_s}`` to its
run folder's ``log.jsonl`` (``time_s``: training wall time so far, validation excluded). A job's
curve (:func:`job_curve`) joins the logs of its runs in order of stages (``train.runs`` of its
metrics) on **cumulative** training time: the samples of a method that builds on Baseline (Ours'
Stage 2, Continued's further steps) are shifted by its Stage 1's training time, so its curve
starts where its Stage 1 (the Baseline of the same seed) starts.

What the SSIM is: the trainer's validation SSIM (metric protocol, at 90 x 360 whatever the training resolution)
on held-out views of the *training* split of the data the stage trains on, not the test set:
empty-room views for Baseline and Stage 1, person-present views for Stage 2 and the person-data
methods. The dynamic test SSIM is known only at the end of a job (a star in the figure).

:func:`on_grid` and :func:`time_to_within` are the pure NumPy parts (seeds on a common time
grid; the time from which a curve stays within ``TOL`` of its final value);
:func:`speed_accuracy` draws ``speed_accuracy.png`` and returns the Markdown section that the
``compare`` and ``reproduce`` reports share.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import plots
from .methods import METHODS
from .results import fmt

TOL = 0.005  # "within 0.005 SSIM of the final value" (the Stage-1 convergence target)


@dataclass
class JobCurve:
    """One job's validation curve: samples ``t`` (cumulative training s) and ``ssim``, the stage
    index of each sample, the cumulative time at each stage's end, the final dynamic test mean
    SSIM and its nearest-neighbour and mean-image floors (None where not evaluated)."""

    method: str
    seed: int
    t: np.ndarray
    ssim: np.ndarray
    stage: np.ndarray
    stage_ends: list[float]
    test: float | None = None
    nn: float | None = None
    mean_image: float | None = None

    def last_stage(self) -> tuple[np.ndarray, np.ndarray]:
        """Samples of the last stage (the one the final SSIM belongs to)."""
        k = self.stage == self.stage[-1]
        return self.t[k], self.ssim[k]


def val_rows(run_dir: Path) -> list[dict]:
    """Validation rows (finite ``val_ssim``) of a trainer run folder's ``log.jsonl``."""
    log = Path(run_dir) / "log.jsonl"
    rows = [json.loads(ln) for ln in log.read_text().splitlines() if ln.strip()] if log.is_file() else []
    return [r for r in rows if r.get("val_ssim") is not None and math.isfinite(r["val_ssim"])]


def job_curve(method: str, seed: int, result: dict) -> JobCurve | None:
    """The curve of one finished job from the run folders its metrics name (``train.runs``, in
    order of stages); None when a run folder or its log is not found (moved, or a relative path
    from another working directory)."""
    t, s, st, ends, offset = [], [], [], [], 0.0
    for i, rd in enumerate(result.get("train", {}).get("runs", [])):
        summary = Path(rd) / "final" / "summary.json"
        rows = val_rows(Path(rd))
        if not rows or not summary.is_file():
            return None
        t += [offset + r["time_s"] for r in rows]
        s += [r["val_ssim"] for r in rows]
        st += [i] * len(rows)
        offset += json.loads(summary.read_text())["train_time_s"]
        ends.append(offset)
    if not t:
        return None
    dyn = result.get("eval", {}).get("dynamic") or {}

    def mean(k):
        return (dyn.get(k) or {}).get("mean")

    return JobCurve(method, seed, np.asarray(t, float), np.asarray(s, float), np.asarray(st), ends,
                    mean("model"), mean("nearest_neighbour"), mean("mean_image"))


def on_grid(curves: list[tuple[np.ndarray, np.ndarray]], n: int = 200) -> dict:
    """Curves ``(t, ssim)`` of several seeds on one time grid.

    The grid runs from the latest first sample to the latest last sample (``n`` points), so every
    seed has a value everywhere: linear between its samples, held at its final value after it
    ended (the trained model does not change once training stopped).

    Returns:
        {"t": grid [n], "mean", "min", "max": over seeds [n], "values": [seeds, n]}.
    """
    if not curves:
        raise ValueError("on_grid: no curves")
    t0 = max(float(t[0]) for t, _ in curves)
    t1 = max(float(t[-1]) for t, _ in curves)
    grid = np.linspace(t0, t1, n)
    v = np.stack([np.interp(grid, np.asarray(t, float), np.asarray(s, float)) for t, s in curves])
    return {"t": grid, "mean": v.mean(0), "min": v.min(0), "max": v.max(0), "values": v}


def time_to_within(t: np.ndarray, ssim: np.ndarray, tol: float = TOL) -> float:
    """The first sampled time from which every later sample is at least ``ssim[-1] - tol``:
    when the curve reached its final value to within ``tol`` and stayed there."""
    ssim = np.asarray(ssim, float)
    bad = np.flatnonzero(ssim < ssim[-1] - tol)
    return float(np.asarray(t, float)[bad[-1] + 1 if bad.size else 0])


def _finite_mean(xs) -> float | None:
    v = [x for x in xs if x is not None and math.isfinite(x)]
    return float(np.mean(v)) if v else None


def _draw(ax, title: str, curves: list[JobCurve]) -> None:
    """One panel: per method the seeds (thin), their mean and min-max band (stage by stage: the
    stages of a two-stage method validate on different views), the stage boundary, the final
    dynamic test SSIM (star); the dynamic-test floors."""
    for i, (m, meth) in enumerate(METHODS.items()):
        cs = [c for c in curves if c.method == m]
        if not cs:
            continue
        col = f"C{i}"
        last = len(cs[0].stage_ends) - 1
        for k in range(last + 1):  # stage by stage: each validates on its own views
            segs = [(c.t[c.stage == k], c.ssim[c.stage == k]) for c in cs]
            for t, s in segs:
                ax.plot(t, s, color=col, lw=0.7, alpha=0.35, marker=".", ms=2)
            g = on_grid(segs)
            # an earlier stage (Ours' Stage 1 = the Baseline) dashed, so the method it is stays visible
            ax.plot(g["t"], g["mean"], color=col, lw=1.8 if k == last else 1.2, ls="-" if k == last else "--",
                    label=f"{meth.label} ({len(cs)} seed{'s' * (len(cs) > 1)})" if k == last
                    else f"{meth.label}: Stage 1")
            if len(cs) > 1:
                ax.fill_between(g["t"], g["min"], g["max"], color=col, alpha=0.12, lw=0)
        if len(cs[0].stage_ends) > 1:  # each seed's own boundary: training times differ between seeds
            for j, c in enumerate(cs):
                ax.axvline(c.stage_ends[0], color=col, ls=":", lw=1, alpha=0.7,
                           label=None if j else f"{meth.label}: Stage 1 ends, Stage 2 starts (per seed)")
        test = _finite_mean(c.test for c in cs)
        if test is not None:
            ax.plot([float(np.mean([c.t[-1] for c in cs]))], [test], marker="*", ms=10, color=col, mec="k", mew=0.5,
                    ls="none")
    for key, ls, name in (("nn", "--", "nearest neighbour"), ("mean_image", "-.", "mean image")):
        v = _finite_mean(getattr(c, key) for c in curves)
        if v is not None:
            ax.axhline(v, color="grey", ls=ls, lw=1, label=f"{name} floor, dynamic test ({v:.3f})")
    ax.plot([], [], marker="*", ms=8, color="w", mec="k", ls="none", label="final dynamic test SSIM")
    ax.set_title(title, fontsize=9)
    plots.label(ax, xlabel="cumulative training wall time (s), Stage 1 + Stage 2",
                ylabel="validation SSIM (held-out training views)", legend_fontsize=6)


def speed_accuracy(path: Path, groups: dict[str, list[tuple[str, int, dict]]]) -> list[str]:
    """Draw ``path`` (one panel per group: validation SSIM against cumulative training time, every
    method) and return the report's Markdown: the figure, what it shows and, per group and method,
    the final validation SSIM, the time to come within :data:`TOL` of it and the training time.
    With no curve to draw (no jobs, or none whose training logs are found) no figure is written,
    an older one at ``path`` is removed, and the Markdown says why.

    Args:
        path: the PNG to write.
        groups: panel title -> [(method, seed, job metrics with ``train.runs`` and ``eval``)].
    """
    path = Path(path)
    curves = {g: [c for c in (job_curve(m, s, r) for m, s, r in jobs) if c is not None] for g, jobs in groups.items()}
    missing = sum(len(jobs) for jobs in groups.values()) - sum(len(c) for c in curves.values())
    shown = [g for g in curves if curves[g]]
    if not shown:
        path.unlink(missing_ok=True)
        if not missing:
            return ["None in this selection: no curve to draw.", ""]
        return [f"No curve to draw: the run folders (`train.runs` of the metrics) or training logs of all {missing} "
                "job(s) were not found from this working directory.", ""]
    ncol = min(3, max(len(shown), 1))
    nrow = max(1, math.ceil(len(shown) / ncol))
    fig, axes = plots.subplots(nrow, ncol, figsize=(6.5 * ncol, 4.5 * nrow), squeeze=False)
    for ax, g in zip(axes.ravel(), shown):
        _draw(ax, g, curves[g])
    for ax in axes.ravel()[len(shown):]:
        ax.set_axis_off()
    plots.save(fig, path, dpi=110)

    L = [f"![validation SSIM against cumulative training time]({path.name})", "",
         "SSIM against training wall time, sampled during training (every `val_every` steps). The SSIM is the "
         "trainer's **validation SSIM on held-out views of the training split** (metric protocol, at 90x360 "
         "whatever the training resolution), not the test set: empty-room views for Baseline and Stage 1, person-present views for "
         "Stage 2 and the methods trained on person-present data. Thin lines: seeds; thick line: their mean on a "
         "common time grid, stage by stage, from when every seed has a sample (a seed that finished holds its "
         "final value); band: min-max over seeds. The time axis is **cumulative** training time: the curve of a "
         "method that builds on Baseline (Ours, Continued) is its Stage 1 (the Baseline of the same seed) and then "
         "its own run (dotted lines: where each seed's own run starts). Stars: the final "
         "dynamic test mean SSIM; grey lines: the nearest-neighbour and mean-image floors of the dynamic test set.", "",
         f"Time to within {TOL} of the final validation SSIM: the first validation from which every later one "
         f"is at least final - {TOL} (per seed; for a method that builds on another, within its last run, on the "
         "cumulative "
         "clock). Mean ± std over seeds.", ""]
    if missing:
        L += [f"{missing} job(s) left out: their run folders (`train.runs` of the metrics) or training logs were "
              "not found from this working directory.", ""]
    L += ["| runs | method | seeds | final validation SSIM | time to within 0.005 (s) | training time (s) | "
          "dynamic test SSIM |", "|---|---|---|---|---|---|---|"]
    for g in shown:
        for m, meth in METHODS.items():
            rows = [{"final": c.ssim[-1], "within": time_to_within(*c.last_stage()), "total": c.stage_ends[-1],
                     "test": c.test} for c in curves[g] if c.method == m]
            if rows:
                L.append(f"| {g} | {meth.label} | {len(rows)} | {fmt(rows, 'final')} | {fmt(rows, 'within', 1)} | "
                         f"{fmt(rows, 'total', 1)} | {fmt(rows, 'test')} |")
    return L + [""]
