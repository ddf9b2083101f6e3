"""Sine-cosine encoding of positions for the fields' networks (host side, NumPy)."""
from __future__ import annotations

import numpy as np


def sin_encoding(x01: np.ndarray, octaves: int) -> np.ndarray:
    """``[x, sin(2 pi 2^k x), cos(2 pi 2^k x)]`` of inputs mapped to [0, 1] (float [K, D]), with
    x = x01 / 2 so that the encoding does not alias over the box: float32 [K, D (1 + 2 octaves)]."""
    x = 0.5 * np.asarray(x01, np.float64)
    parts = [x]
    for k in range(octaves):
        f = 2.0 * np.pi * 2 ** k
        parts += [np.sin(f * x), np.cos(f * x)]
    return np.concatenate(parts, axis=1).astype(np.float32)
