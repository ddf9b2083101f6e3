"""Test helper: line-of-sight spectra of tags seen by a fixed 4 x 4 array (for the frame fit, the
calibration fit and the coherent Gaussian field's use of them)."""
from __future__ import annotations

import numpy as np

#: the carrier of these spectra [Hz] (NeRF2's RFID gateway)
F = 920e6


def los_spectra(*, true_to_world: np.ndarray | None = None, offsets_rad: np.ndarray | None = None, n: int = 40,
                seed: int = 0):
    """Tags in a 1.6 x 1.3 x 0.9 m region about 4.5 m from a fixed 4x4 array at the origin, and the
    phase-only Bartlett PAS of the line of sight alone, seen by an array whose frame -> world is
    ``true_to_world`` (default identity), each element's channel turned by ``offsets_rad`` [16]
    (default none). Returns (pas float [n, 45, 180], x float [n, 3], y float [n, 3]) [m]."""
    from rfmitsuba.rf import array as antenna
    from rfmitsuba.rf.bartlett_ref import bartlett, normalize

    rng = np.random.default_rng(seed)
    y = np.array([-1.5, 1.0, 4.0]) + rng.random((n, 3)) * [1.6, 1.3, 0.9]
    x = np.zeros((n, 3))
    u = (y - x) / np.linalg.norm(y - x, axis=1, keepdims=True)
    if true_to_world is not None:
        u = u @ true_to_world                                     # array-frame directions
    h = antenna.array_response(np.ones((n, 1)), u[:, None, :], frequency_hz=F)
    if offsets_rad is not None:
        h = h * np.exp(1j * np.asarray(offsets_rad))[None]
    return normalize(bartlett(h, frequency_hz=F, resolution_deg=2.0, phase_only=True)), x, y
