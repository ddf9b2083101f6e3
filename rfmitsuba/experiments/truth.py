"""The ground truth's own error bar: Sionna's synthetic array against tracing every element.

Datasets are simulated with Sionna's synthetic array: one ray trace per array position, each
element's phase by the plane-wave rule about the array centre (``generate --array synthetic``,
the default). :func:`truth_uncertainty` generates the same positions, seeds and scene a second
time with ``--array exact`` (each of the 16 elements traced as its own antenna,
:meth:`rfmitsuba.sim.simulate.Simulator.channels`) and compares the two per PAS:

- channel correlation ``|<h_syn, h_exact>| / (|h_syn| |h_exact|)`` over the 16 elements;
- power difference ``10 log10(|h_exact|^2 / |h_syn|^2)`` in dB;
- PAS SSIM by the metric protocol (:func:`rfmitsuba.core.ssim.ssim_images` on min-max
  normalised 90 x 360 PAS, exact as the reference).

The SSIM between the two truths is the "truth uncertainty band": a model's SSIM against the
synthetic-array truth cannot be read as better than this agreement. With ``repeat`` (default)
the exact truth is traced once more with the next solver seed: that agreement is the ray
sampling's share, so the report says how much of the band is physics and how much noise.
Written to ``OUT``: ``synthetic/``, ``exact/`` and ``exact_reseeded/`` (ordinary datasets,
resumable), ``table.md``, ``summary.json`` (per-PAS values) and ``truth_ssim.png``.
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import plots
from ..core.atomic import numpy_default, write_json, write_text
from ..core.errors import ConfigError, DatasetError
from ..core.ssim import ssim_images
from ..data.store import resolve_scene
from ..eval.metrics import stats
from ..rf import bartlett_ref as pas

#: the statistics reported for each measure
STATS = ("mean", "median", "p10", "min", "max")

#: where ``reproduce`` keeps its truth checks, one folder per room and task (:func:`truth_folder`)
TRUTH_FOLDER = "truth"


def truth_folder(out: str | Path, scene: str, task: str) -> Path:
    """The truth check of ``scene`` and ``task`` inside the reproduction folder ``out``."""
    return Path(out) / TRUTH_FOLDER / f"{scene}_{task}"


def load_summary(folder: str | Path) -> dict | None:
    """The ``summary.json`` of a finished :func:`truth_uncertainty` in ``folder``, or None where there is none."""
    f = Path(folder) / "summary.json"
    return json.loads(f.read_text()) if f.is_file() else None


@dataclass
class TruthConfig:
    """What :func:`truth_uncertainty` simulates, twice (synthetic and exact array)."""

    scene: str = "bedroom"
    task: str = "rx"
    positions: int = 48
    #: person positions along the walk (0: the empty room only)
    person_positions: int = 0
    seed: int = 0
    #: ray samples per source (None: the room's default, as ``generate``)
    samples: int | None = None
    #: Dr.Jit threads of the solver (1: bit-reproducible)
    threads: int = 1
    #: also trace the exact truth with the next solver seed (the ray-sampling noise floor)
    repeat: bool = True


def compare_channels(h_syn: np.ndarray, h_exact: np.ndarray, *, frequency_hz: float) -> dict[str, np.ndarray]:
    """Per-PAS agreement of two channel sets, complex [K, 16] each.

    Returns:
        {"correlation": float64 [K] in [0, 1], "power_db": float64 [K] (exact over synthetic),
        "ssim": float64 [K] (PAS SSIM by the metric protocol, exact as the reference)}.
    """
    a = np.asarray(h_syn, np.complex128)
    b = np.asarray(h_exact, np.complex128)
    if a.shape != b.shape or a.ndim != 2:
        raise ConfigError(f"channel sets must have one shape [K, M], got {a.shape} and {b.shape}")
    na, nb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
    if not (np.all(na > 0) and np.all(nb > 0)):
        raise ConfigError("a channel is zero (no path reached the array); the comparison is undefined")
    corr = np.abs(np.sum(np.conj(a) * b, axis=1)) / (na * nb)
    power_db = 20 * np.log10(nb / na)
    ps = pas.normalize(pas.bartlett(a, frequency_hz=frequency_hz))
    pe = pas.normalize(pas.bartlett(b, frequency_hz=frequency_hz))
    return {"correlation": corr, "power_db": power_db, "ssim": ssim_images(ps, pe)}


def summarise(x: np.ndarray) -> dict[str, float]:
    """Mean, median, 10th percentile, min (:func:`rfmitsuba.eval.metrics.stats`) and max of a 1-D array."""
    out = {k: v for k, v in stats(x).items() if k in STATS}
    out["max"] = float(np.max(x))
    return out


def truth_uncertainty(out: str | Path, cfg: TruthConfig | None = None, *, quiet: bool = False) -> dict:
    """Generate ``cfg`` with the synthetic and the exact array into ``out`` and compare them.

    Both datasets share scene, task, positions, walk and solver seeds (only ``array`` differs);
    an interrupted run resumes. Returns the summary written to ``out/summary.json``:
    ``{"config", "frequency_hz", "count", "stats": {measure: {stat: value}}, "per_pas": [...]}``.
    """
    from ..sim import generate as gen
    from ..sim.geometry import RoomGeometry
    from ..sim.simulate import SolverConfig

    cfg = cfg or TruthConfig()
    if cfg.positions > gen.EXACT_MAX_POSITIONS:
        raise ConfigError(f"positions: the exact array takes at most {gen.EXACT_MAX_POSITIONS}, got {cfg.positions}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    base = gen.default_solver(RoomGeometry.from_xml(resolve_scene(cfg.scene)))
    solver = SolverConfig(samples_per_src=int(cfg.samples or base.samples_per_src), threads=cfg.threads)
    runs = {"synthetic": ("synthetic", solver), "exact": ("exact", solver)}
    if cfg.repeat:
        runs["exact_reseeded"] = ("exact", dataclasses.replace(solver, seed=solver.seed + 1))
    made = {}
    for name, (array, sc) in runs.items():
        g = gen.GenerateConfig(scene=cfg.scene, task=cfg.task, positions=cfg.positions,
                               person_positions=cfg.person_positions, seed=cfg.seed, array=array, solver=sc)
        made[name] = gen.generate(out / name, g, quiet=quiet)
    syn, ex = made["synthetic"], made["exact"]
    for d in made.values():
        if not np.array_equal(syn.antenna_pos, d.antenna_pos) or syn.num_states != d.num_states:
            raise DatasetError(f"{out}: the synthetic and exact datasets hold different positions")
    rows, parts = _compare(syn, ex)
    summary = {"config": vars(cfg), "frequency_hz": syn.frequency_hz, "solver": syn.meta.get("solver"),
               "count": len(rows), "stats": {k: summarise(v) for k, v in parts.items()}, "per_pas": rows}
    if cfg.repeat:
        _, noise = _compare(ex, made["exact_reseeded"])
        summary["noise"] = {"solver_seeds": [solver.seed, solver.seed + 1],
                            "stats": {k: summarise(v) for k, v in noise.items()}}
    write_json(out / "summary.json", summary, default=numpy_default)
    write_report(out, summary)
    return summary


def _compare(a, b) -> tuple[list[dict], dict[str, np.ndarray]]:
    """Per-PAS rows and the measures over every state of two datasets of the same positions."""
    rows, parts = [], {k: [] for k in ("correlation", "power_db", "ssim")}
    dist = np.linalg.norm(a.antenna_pos.astype(np.float64) - a.fixed_pos, axis=1)
    for s in range(a.num_states):
        c = compare_channels(a.channel(s), b.channel(s), frequency_hz=a.frequency_hz)
        for k, v in parts.items():
            v.append(c[k])
        for i in range(a.num_antennas):
            rows.append({"state": s, "position": i, "antenna_pos": a.antenna_pos[i].tolist(),
                         "distance_m": float(dist[i]), **{k: float(c[k][i]) for k in parts}})
    return rows, {k: np.concatenate(v) for k, v in parts.items()}


def write_report(out: str | Path, summary: dict) -> Path:
    """``out/table.md`` (the statistics and every PAS) and ``out/truth_ssim.png`` from a summary."""
    out = Path(out)
    c, st, rows = summary["config"], summary["stats"], summary["per_pas"]
    names = {"ssim": "PAS SSIM (metric protocol)", "correlation": "channel correlation",
             "power_db": "power difference, exact - synthetic [dB]"}
    cmd = (f"rfmitsuba experiment truth --scene {c['scene']} --task {c['task']} --positions {c['positions']}"
           + (f" --person-positions {c['person_positions']}" if c["person_positions"] else "")
           + (f" --samples {c['samples']}" if c.get("samples") else "") + f" --seed {c['seed']}"
           + ("" if c.get("repeat", True) else " --no-repeat") + " --out DIR")
    samples = (summary.get("solver") or {}).get("samples_per_src")
    title = f"# Truth uncertainty: synthetic array against exact per-element tracing ({c['scene']}, moving " \
            f"{c['task'].upper()})"
    lines = [title, "",
             f"{summary['count']} PAS: {c['positions']} antenna positions x {1 + c['person_positions']} state(s), "
             f"seed {c['seed']}" + (f", {samples:.0f} ray samples per source" if samples else "") + ". "
             "Synthetic: one trace per array position, element phases by the plane-wave rule (how every "
             "dataset is made). Exact: each of the 16 elements traced as its own antenna. SSIM is the "
             "metric protocol's (min-max normalised 90 x 360 PAS, skimage, 7 x 7 window); no model can be "
             "judged above this agreement with the synthetic-array truth.", "",
             f"Regenerate: `{cmd}`", "",
             "| measure | mean | median | 10th pct | min | max |", "|---|---|---|---|---|---|"]
    for k in ("ssim", "correlation", "power_db"):
        f = "{:+.2f}" if k == "power_db" else "{:.3f}"
        lines.append(f"| {names[k]} | " + " | ".join(f.format(st[k][s]) for s in STATS) + " |")
    if "noise" in summary:
        n = summary["noise"]
        seeds = n["solver_seeds"]
        what = (f"Ray-sampling share: the exact truth against itself traced with solver seed {seeds[1]} "
                f"instead of {seeds[0]} (same positions and samples).")
        lines += ["", what, "",
                  "| measure, exact vs exact reseeded | mean | median | 10th pct | min | max |",
                  "|---|---|---|---|---|---|"]
        for k in ("ssim", "correlation", "power_db"):
            f = "{:+.2f}" if k == "power_db" else "{:.3f}"
            name = "power difference, reseeded - exact [dB]" if k == "power_db" else names[k]
            lines.append(f"| {name} | " + " | ".join(f.format(n["stats"][k][s]) for s in STATS) + " |")
    lines += ["", "Per PAS (worst SSIM first):", "",
              "| state | position | x, y, z [m] | distance to fixed device [m] | SSIM | correlation | power [dB] |",
              "|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: r["ssim"]):
        p = ", ".join(f"{v:.2f}" for v in r["antenna_pos"])
        lines.append(f"| {r['state']} | {r['position']} | {p} | {r['distance_m']:.2f} | {r['ssim']:.3f} | "
                     f"{r['correlation']:.4f} | {r['power_db']:+.2f} |")
    write_text(out / "table.md", "\n".join(lines) + "\n")
    _plot(out / "truth_ssim.png", rows, st, title=f"{c['scene']}, moving {c['task'].upper()}, {len(rows)} PAS")
    return out / "table.md"


def _plot(path: Path, rows: list[dict], stats: dict, *, title: str) -> None:
    ssim = np.sort([r["ssim"] for r in rows])
    fig, (a0, a1) = plots.subplots(1, 2, figsize=(9.5, 3.6))
    a0.step(ssim, np.arange(1, len(ssim) + 1) / len(ssim), where="post", label="PAS SSIM, synthetic vs exact")
    a0.axvline(stats["ssim"]["mean"], color="k", ls="--", lw=1, label=f"mean {stats['ssim']['mean']:.3f}")
    a0.axvline(stats["ssim"]["median"], color="grey", ls=":", lw=1, label=f"median {stats['ssim']['median']:.3f}")
    a0.set_title(title, fontsize=9)
    plots.label(a0, xlabel="SSIM", ylabel="fraction of PAS")
    d = np.array([r["distance_m"] for r in rows])
    sc = a1.scatter(d, [r["ssim"] for r in rows], c=[r["correlation"] for r in rows], s=14, cmap="viridis")
    fig.colorbar(sc, ax=a1, label="channel correlation")
    plots.label(a1, xlabel="distance to the fixed device [m]", ylabel="PAS SSIM", legend_fontsize=None)
    plots.save(fig, path)
