"""Synthetic dynamic datasets rendered from known Gaussians (no Sionna).

:func:`make_dataset` places a known background (Gaussians on the walls of a box room plus a
bright source near the fixed transmitter) and a known "person" (a column of absorbing,
weakly scattering Gaussians standing at each person position), renders the PAS of every
(state, antenna) pair with :func:`rfmitsuba.splat.render`, and writes them with
:func:`rfmitsuba.data.store.write_dataset`. Used by the tests and the ``tiny`` experiment size.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.errors import ConfigError
from ..data.store import write_dataset
from ..splat import render

ROOM = np.array([[0.0, 0.0, 0.0], [4.0, 3.5, 2.8]])


def _background(rng: np.random.Generator, n: int) -> dict:
    lo, hi = ROOM
    pts = lo + rng.random((n, 3)) * (hi - lo)
    face = rng.integers(0, 6, n)
    for i, f in enumerate(face):
        ax, side = f // 2, f % 2
        pts[i, ax] = hi[ax] if side else lo[ax]
    src = np.array([[3.7, 3.2, 2.0]])
    means = np.concatenate([pts, src])
    sig = np.concatenate([0.2 + 0.6 * rng.random(n), [2.0]])
    op = np.concatenate([0.2 + 0.3 * rng.random(n), [0.5]])
    scales = np.concatenate([0.15 + 0.2 * rng.random(n), [0.08]])
    return {"means": means, "scales": scales, "signals": sig, "opacities": op}


def _person(pos: np.ndarray, k: int = 8) -> dict:
    z = np.linspace(0.2, 1.7, k)
    means = np.stack([np.full(k, pos[0]), np.full(k, pos[1]), z], 1)
    return {"means": means, "scales": np.full(k, 0.14), "signals": np.full(k, 0.9), "opacities": np.full(k, 0.9)}


def render_sets(sets: list[dict], views: np.ndarray, *, height: int = 90, width: int = 360) -> np.ndarray:
    """Render isotropic Gaussian sets (dicts of means [N, 3] m, scales [N] m, signals [N],
    opacities [N]) together at array positions ``views`` float [B, 3]: float32 [B, height, width]."""

    means = np.concatenate([s["means"] for s in sets]).astype(np.float32)
    n = len(means)
    ls = np.repeat(np.log(np.concatenate([s["scales"] for s in sets]))[:, None], 3, 1).astype(np.float32)
    rot = np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1))
    op = np.concatenate([s["opacities"] for s in sets]).astype(np.float32)
    sig = np.concatenate([s["signals"] for s in sets]).astype(np.float32)
    out = []
    for i in range(0, len(views), 8):
        img = render(means, ls, rot, op, sig, np.asarray(views[i:i + 8], np.float32), height=height, width=width)
        out.append(np.asarray(img.numpy(), np.float32).reshape(-1, height, width))
    return np.concatenate(out)


def make_dataset(path: str | Path, *, antennas: int = 30, people: int = 6, background: int = 60,
                 seed: int = 0, task: str = "rx"):
    """Write a synthetic dataset (moving-RX geometry) and return it opened.

    Args:
        path: new folder.
        antennas: A antenna positions (uniform in the room's middle, metres).
        people: H person positions on a walk across the floor.
        background: number of wall Gaussians.
        seed: randomness of the scene and positions.
        task: recorded task ("rx" renders from the antenna positions).
    """

    if antennas < 5 or people < 2:
        raise ConfigError(f"make_dataset needs >= 5 antennas and >= 2 people, got {antennas}, {people}")
    rng = np.random.default_rng(seed)
    bg = _background(rng, background)
    ant = np.stack([0.6 + 2.8 * rng.random(antennas), 0.6 + 2.3 * rng.random(antennas),
                    0.5 + 1.2 * rng.random(antennas)], 1)
    t = np.linspace(0, 1, people)
    walk = np.stack([0.8 + 2.4 * t, 1.0 + 1.5 * np.sin(np.pi * t) * 0.8, np.zeros(people)], 1)
    walk[:, :2] += rng.normal(0, 0.05, (people, 2))
    pas = [render_sets([bg], ant)]
    for h in walk:
        pas.append(render_sets([bg, _person(h)], ant))
    hp = np.concatenate([np.full((1, 3), np.nan), walk])
    return write_dataset(path, pas=np.stack(pas), antenna_pos=ant, person_pos=hp, seed=seed,
                         meta={"task": task, "fixed_pos": [3.7, 3.2, 2.0], "synthetic": {"seed": seed}})
