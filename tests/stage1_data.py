"""Tiny synthetic datasets for the Stage-1 tests: PAS rendered from known Gaussians.

The ground truth is made by the project's own renderer (``rfmitsuba.splat.render``) from
a random field, so a model of the same family can fit it; images are 90 x 360 as every
dataset, training in the tests runs at ``downsample=5`` (18 x 72).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

BOX = np.array([[0.0, 0.0, 0.0], [4.0, 3.5, 2.5]])


def known_field(seed: int = 7, n: int = 30):
    """A random ground-truth field: n Gaussians of 0.3 m, opacity 0.5, network seed ``seed``."""
    from rfmitsuba.models.splat import SplatConfig, SplatField

    rng = np.random.default_rng(seed)
    pts = rng.uniform(BOX[0], BOX[1], (n, 3))
    return SplatField.from_points(pts, cfg=SplatConfig(init_scale=0.3, init_opacity=0.5), box=BOX, seed=seed)


def render_pas(field, antenna_pos: np.ndarray, view_pos: np.ndarray) -> np.ndarray:
    """float32 [A, 90, 360] raw PAS of ``field`` (no gradients)."""
    import drjit as dr

    from rfmitsuba.splat import render

    out = []
    for i in range(0, len(antenna_pos), 16):
        with dr.suspend_grad():
            s = field.splats(antenna_pos[i:i + 16], view_pos=view_pos[i:i + 16])
            img = render(s.means, s.log_scales, s.rotations, s.opacities, s.signals, view_pos[i:i + 16])
        out.append(np.array(img.numpy(), np.float32).reshape(-1, 90, 360))
    return np.concatenate(out)


def make_dataset(path: Path, *, num_antennas: int = 60, task: str = "rx", seed: int = 0) -> Path:
    """Write a one-state (empty room) dataset of ``num_antennas`` positions; returns its folder."""
    from rfmitsuba.data.store import write_dataset

    rng = np.random.default_rng(seed)
    ap = rng.uniform([0.5, 0.5, 0.8], [3.5, 3.0, 1.6], (num_antennas, 3))
    fixed = np.array([0.3, 0.3, 2.0])
    view = ap if task == "rx" else np.tile(fixed, (num_antennas, 1))
    pas = render_pas(known_field(), ap, view)
    write_dataset(path, pas=pas[None], antenna_pos=ap, person_pos=np.full((1, 3), np.nan),
                  meta={"task": task, "fixed_pos": fixed.tolist()}, seed=seed)
    return Path(path)


def tiny_cfg(**over):
    """A TrainConfig for tests: 40 steps on 18 x 72 block means, a small splat field, with ``over``
    (option -> TOML value) on top."""
    from rfmitsuba.core import config as C
    from rfmitsuba.train.config import TrainConfig

    cfg = TrainConfig()
    sets = ['model="splat"', "iterations=40", "downsample=5", "val_every=10", "checkpoint_every=10", "log_every=5",
            "val_fraction=0.1", "splat.init=\"random\"", "splat.num_gaussians=150", "splat.net.width=16",
            "splat.net.gaussian_octaves=2", "splat.net.antenna_octaves=2", "density.start=10",
            "density.every=20", "density.reset_every=30", "density.max_gaussians=400",
            "density.grad_threshold=1e-5", "optim.lr_net=5e-3"]
    return C.override(cfg, sets + [f"{k}={v}" for k, v in over.items()])
