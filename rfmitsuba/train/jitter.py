"""Jittered training views: each training spectrum is also the target a small random distance
away from where it was measured.

Where the data stop, a coherent field must guess how its paths' relative phases go on, and a fit
that matches every training position can still change much faster than the data do just past
them. On the NeRF2-like spatial-block split (the test tags a slab 0.9-17 cm past the training
tags, spectra 1-5 cm apart scoring 0.90-0.96 against each other) one field fit the training tags
at 0.955-0.965 SSIM and scored 0.81 on test tags within 6 cm of them, where the nearest training
spectrum scores 0.943 (docs/lab-notes/nerf2like.md).

With ``TrainConfig.jitter`` = ``s`` > 0 every step adds one copy of its
batch whose moving device (the transmitter in the moving-TX task, the array with the receiver in
the moving-RX task) is displaced by ``N(0, (s lambda)^2)`` per axis, ``lambda`` the carrier
wavelength, each with the spectrum of the view it was copied from as its target. The training
loss then also asks the field to change no faster across about ``s lambda`` than the data: a
prior of the data's own smoothness, in the spirit of the unseen-view regularisers of few-view
neural fields (RegNeRF), with the measured spectra as targets instead of a learned prior.
"""
from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError
from ..models.base import Views
from ..rf import array as antenna


def jittered(views: Views, gt: np.ndarray, *, spread: float, copies: int,
             rng: np.random.Generator) -> tuple[Views, np.ndarray]:
    """A batch and ``copies`` jittered copies of it.

    Args:
        views: the batch's B views; gt: float32 [B, H, W] their target spectra.
        spread: standard deviation of the displacement per axis [carrier wavelengths], > 0.
        copies: jittered copies of the batch, >= 1.
        rng: draws the displacements (the trainer's generator, so a resumed run draws the same).

    Returns:
        (views of (1 + copies) * B: the batch first, then each copy; float32 [(1 + copies) * B,
        H, W]: ``gt`` repeated in the same order).
    """
    if not (spread > 0 and np.isfinite(spread)) or copies < 1:
        raise ConfigError(f"jittered views need spread > 0 wavelengths and copies >= 1, got {spread!r} and {copies!r}")
    sigma = float(spread) * antenna.wavelength(views.frequency_hz)
    moved = [views.moved(rng.normal(0.0, sigma, (views.count, 3))) for _ in range(int(copies))]
    return Views.concat([views] + moved), np.concatenate([gt] * (1 + int(copies)))
