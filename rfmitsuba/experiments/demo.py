"""The README's main job on the built-in bedroom: data, Baseline, Ours, End-to-End, report.

:func:`run_demo` generates a small but real bedroom moving-RX dataset with a walk of person
positions (Sionna RT; skipped when present), trains Baseline (= Stage 1), Ours (Stage 2 on top)
and End-to-End with equal budgets, evaluates dynamic and static SSIM with both floors and writes
``OUT/report.md`` with ``OUT/dynamic_grid.png`` and ``OUT/ssim_cdf.png``. Every step resumes.
"""
from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from ..core import config as C
from ..core import plots
from ..core.errors import ConfigError
from ..data.views import TrainData
from ..eval.dynamic_static import evaluate
from ..eval.figures import plot_cdf
from .methods import load_model, train_method
from .sizes import ExperimentConfig, method_config, size_config


def run_demo(out: str | Path, *, cfg: ExperimentConfig | None = None, quiet: bool = False,
             dataset: str | Path | None = None) -> Path:
    """Run the demo into ``out``; returns the report path.

    Args:
        out: output folder (created; resumes).
        cfg: the sizes (default ``SIZES["demo"]`` of :mod:`rfmitsuba.experiments.sizes`): ``data``
            (positions, walk positions, ray samples), ``train`` (every method's sizes),
            ``rooms[0]`` (the built-in scene) and ``seeds[0]`` (data and training seed).
        quiet: no progress bars.
        dataset: use this dataset folder instead of generating ``out/data``.
    """

    cfg = cfg or size_config("demo")
    d, seed, scene = cfg.data, cfg.seeds[0], cfg.rooms[0]
    if d.positions < 10 or d.person_positions < 2:
        raise ConfigError("the demo needs data.positions >= 10 and data.person_positions >= 2")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    if dataset is None:
        from ..sim import generate as gen
        from ..sim.simulate import SolverConfig

        dataset = out / "data"
        g = gen.GenerateConfig(scene=scene, task="rx", positions=d.positions, person_positions=d.person_positions,
                               seed=seed, solver=SolverConfig(samples_per_src=d.samples_per_src))
        gen.generate(dataset, g, quiet=quiet)
    t_data = time.perf_counter() - t0

    has_scene = TrainData.open(dataset).scene_xml is not None
    # the image-source model needs the room's geometry; the others start from the data without one
    train = cfg.train if has_scene or cfg.train.model != "coherent" else dataclasses.replace(cfg.train, model="splat")
    model = train.model
    mcfg = method_config(train, scene_known=has_scene)
    C.save(mcfg, out / "method_config.toml") if not (out / "method_config.toml").exists() else None
    res = {}
    for m in ("baseline", "ours", "end_to_end"):
        t1 = time.perf_counter()
        tr = train_method(m, dataset, out / m, mcfg=mcfg, seed=seed, quiet=quiet,
                          stage1_dir=(out / "baseline" / "train") if m == "ours" else None)
        ev = evaluate(load_model(m, out / m), dataset, keep=True)
        res[m] = {"train": tr, "eval": ev, "wall_s": time.perf_counter() - t1}
    _plots(out, res)
    lines = [f"# rfmitsuba demo: Baseline vs Ours vs End-to-End ({model} model)", "",
             *([f"The dataset names no scene, so the {model} model is used instead of {cfg.train.model}.", ""]
               if model != cfg.train.model else []),
             f"Dataset `{dataset}` ({scene}, moving RX, {d.positions} antenna positions x (1 + "
             f"{d.person_positions}) states; data step {t_data:.0f} s). Budgets: Baseline {train.stage1_iterations} "
             f"steps; Ours = Baseline + {train.stage2_iterations} Stage-2 steps; End-to-End "
             f"{train.stage1_iterations + train.stage2_iterations} steps.", "",
             "| method | dynamic mean | dynamic median | static mean | static median | train s | render ms/PAS |",
             "|---|---|---|---|---|---|---|"]
    for m, r in res.items():
        d, s = r["eval"]["dynamic"], r["eval"]["static"]
        lines.append(f"| {m} | {d['model']['mean']:.3f} | {d['model']['median']:.3f} | {s['model']['mean']:.3f} | "
                     f"{s['model']['median']:.3f} | {r['train']['train_time_s']:.1f} | {r['eval']['render_ms_per_pas']:.1f} |")
    d, s = res["baseline"]["eval"]["dynamic"], res["baseline"]["eval"]["static"]
    lines.append(f"| nearest neighbour | {d['nearest_neighbour']['mean']:.3f} | {d['nearest_neighbour']['median']:.3f} | "
                 f"{s['nearest_neighbour']['mean']:.3f} | {s['nearest_neighbour']['median']:.3f} | | |")
    lines.append(f"| mean image | {d['mean_image']['mean']:.3f} | {d['mean_image']['median']:.3f} | "
                 f"{s['mean_image']['mean']:.3f} | {s['mean_image']['median']:.3f} | | |")
    lines += ["", "Dynamic: unseen antenna x unseen person positions (person-present ground truth); static: the "
              "background alone at unseen antenna positions (empty room).", ""]
    for m, r in res.items():
        for part in ("dynamic", "static"):
            if not r["eval"][part]["beats_nearest_neighbour"]:
                lines.append(f"- {m} does NOT beat the nearest-neighbour floor in the {part} evaluation.")
    lines += ["", "![dynamic test PAS](dynamic_grid.png)", "", "![SSIM CDF](ssim_cdf.png)", "",
              f"Total wall time {time.perf_counter() - t0:.0f} s.", ""]
    summary = {m: {"train": r["train"], "eval": {p: {k: v for k, v in r["eval"][p].items()
                                                    if k in ("model", "nearest_neighbour", "mean_image",
                                                             "beats_nearest_neighbour")}
                                                for p in ("dynamic", "static")},
                   "render_ms_per_pas": r["eval"]["render_ms_per_pas"]} for m, r in res.items()}
    (out / "metrics.json").write_text(json.dumps(summary, indent=1))
    path = out / "report.md"
    path.write_text("\n".join(lines))
    return path


def _plots(out: Path, res: dict) -> None:

    plot_cdf(out / "ssim_cdf.png", {f"{m} dynamic": r["eval"]["dynamic"]["model_ssim"] for m, r in res.items()})
    gt = res["ours"]["eval"]["dynamic"]["gt"]
    k = min(4, len(gt))
    pick = np.linspace(0, len(gt) - 1, k).astype(int)
    cols = [("ground truth", gt)] + [(m, r["eval"]["dynamic"]["pred"]) for m, r in res.items()] + \
        [("nearest neighbour", res["ours"]["eval"]["dynamic"]["nn"])]
    fig, axes = plots.subplots(k, len(cols), figsize=(3 * len(cols), 1.4 * k + 0.5), squeeze=False)
    for r_i, i in enumerate(pick):
        for c_i, (name, imgs) in enumerate(cols):
            ax = axes[r_i, c_i]
            ax.imshow(imgs[i], origin="lower", aspect="auto", extent=(0, 360, 1, 90), vmin=0, vmax=1)
            if r_i == 0:
                ax.set_title(name, fontsize=8)
            ax.tick_params(labelsize=5)
    plots.save(fig, out / "dynamic_grid.png", dpi=100)
