"""The README's main job on the built-in bedroom: data, Baseline, Ours, End-to-End, report.

:func:`run_demo` generates a small but real bedroom moving-RX dataset with a walk of human
positions (Sionna RT; skipped when present), trains Baseline (= Stage 1), Ours (Stage 2 on top)
and End-to-End with equal budgets, evaluates dynamic and static SSIM with both floors and writes
``OUT/report.md`` with ``OUT/dynamic_grid.png`` and ``OUT/ssim_cdf.png``. Every step resumes.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import plots
from ..core.errors import ConfigError


@dataclass
class DemoConfig:
    """Sizes and model of the demo (defaults finish in about 10 minutes on 2 idle cores).

    model: "coherent" (image sources + Bartlett readout, :mod:`rfmitsuba.models.coherent`; ``downsample``
    and the Gaussian counts are not used) or "splat" (Gaussian splatting, WRF-GS+ style).
    """

    positions: int = 300
    human_positions: int = 8
    samples_per_src: int = 20000
    stage1_iterations: int = 600
    stage2_iterations: int = 300
    downsample: int = 3
    num_gaussians: int = 1500
    human_gaussians: int = 96
    seed: int = 0
    model: str = "coherent"
    room_order: int = 2


SIZES = {"default": DemoConfig(),
         "tiny": DemoConfig(positions=30, human_positions=5, stage1_iterations=40, stage2_iterations=30,
                            downsample=10, num_gaussians=200, human_gaussians=24, room_order=1)}


def run_demo(out: str | Path, *, cfg: DemoConfig | None = None, scene: str = "bedroom", quiet: bool = False,
             dataset: str | Path | None = None) -> Path:
    """Run the demo into ``out``; returns the report path.

    Args:
        out: output folder (created; resumes).
        cfg: sizes (default :class:`DemoConfig`).
        scene: built-in scene name.
        quiet: no progress bars.
        dataset: use this dataset folder instead of generating ``out/data``.
    """
    from ..core import config as C
    from ..eval.dynamic_static import evaluate
    from ..models.coherent import CoherentConfig
    from ..models.splat import FieldConfig
    from ..models.splat_person import SplatPersonConfig
    from ..train.config import TrainConfig
    from ..train.density import DensityConfig
    from .methods import MethodConfig, load_model, train_method

    cfg = cfg or DemoConfig()
    if cfg.positions < 10 or cfg.human_positions < 2:
        raise ConfigError("DemoConfig needs >= 10 positions and >= 2 human positions")
    if cfg.model not in ("coherent", "splat"):
        raise ConfigError(f"DemoConfig.model must be 'coherent' or 'splat', got {cfg.model!r}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    if dataset is None:
        from ..sim import generate as gen
        from ..sim.simulate import SolverConfig

        dataset = out / "data"
        g = gen.GenerateConfig(scene=scene, task="rx", positions=cfg.positions, human_positions=cfg.human_positions,
                             seed=cfg.seed, solver=SolverConfig(samples_per_src=cfg.samples_per_src))
        gen.generate(dataset, g, quiet=quiet)
    t_data = time.perf_counter() - t0
    from ..data.views import TrainData

    has_scene = TrainData.open(dataset).scene_xml is not None
    init = "mesh" if has_scene else "random"
    model = cfg.model if has_scene else "splat"  # the coherent model needs the room's geometry
    if model == "coherent":
        s1 = TrainConfig(model="coherent", iterations=cfg.stage1_iterations, batch_views=8, downsample=1,
                         val_every=100, checkpoint_every=100,
                         coherent=CoherentConfig(room_order=cfg.room_order, furniture_order=1))
    else:
        s1 = TrainConfig(iterations=cfg.stage1_iterations, downsample=cfg.downsample, val_every=100,
                         checkpoint_every=100, field=FieldConfig(init=init, num_gaussians=cfg.num_gaussians),
                         density=DensityConfig(start=cfg.stage1_iterations // 4,
                                               every=max(1, cfg.stage1_iterations // 8),
                                               max_gaussians=3 * cfg.num_gaussians))
    mcfg = MethodConfig(stage1=s1, stage2_iterations=cfg.stage2_iterations,
                        human=SplatPersonConfig(num_gaussians=cfg.human_gaussians))
    C.save(mcfg, out / "method_config.toml") if not (out / "method_config.toml").exists() else None
    res = {}
    for m in ("baseline", "ours", "end_to_end"):
        t1 = time.perf_counter()
        tr = train_method(m, dataset, out / m, mcfg=mcfg, seed=cfg.seed, quiet=quiet,
                          stage1_dir=(out / "baseline" / "train") if m == "ours" else None)
        ev = evaluate(load_model(m, out / m), dataset, keep=True)
        res[m] = {"train": tr, "eval": ev, "wall_s": time.perf_counter() - t1}
    _plots(out, res)
    lines = [f"# rfmitsuba demo: Baseline vs Ours vs End-to-End ({model} model)", "",
             *([f"The dataset names no scene, so the {model} model is used instead of {cfg.model}.", ""]
               if model != cfg.model else []),
             f"Dataset `{dataset}` ({scene}, moving RX, {cfg.positions} antenna positions x (1 + "
             f"{cfg.human_positions}) states; data step {t_data:.0f} s). Budgets: Baseline {cfg.stage1_iterations} "
             f"steps; Ours = Baseline + {cfg.stage2_iterations} Stage-2 steps; End-to-End "
             f"{cfg.stage1_iterations + cfg.stage2_iterations} steps.", "",
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
    lines += ["", "Dynamic: unseen antenna x unseen human positions (human-present ground truth); static: the "
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
    from ..eval.figures import plot_cdf

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
