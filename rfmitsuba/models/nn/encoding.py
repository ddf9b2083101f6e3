"""Positional encodings of scalar network inputs (sines or triangle waves, ``drjit.nn``)."""
from __future__ import annotations


def encode(inputs: list, *, octaves: int, kind: str = "sin") -> list:
    """Positional encoding of scalar inputs.

    Args:
        inputs: list of D ``Float`` arrays of equal size M, values in about [0, 1].
        octaves: number of frequencies (0 = raw inputs only).
        kind: "sin" (sin/cos of 2*pi*2^k*x) or "tri" (triangle-wave approximation).

    Returns:
        list of D * (1 + 2 * octaves) ``Float`` arrays of size M: the raw inputs, then the
        encodings. The sine encoding has period 1 in x; callers map their inputs into
        [0, 0.5] so that no two points of the domain alias.
    """
    import drjit.nn as nn

    out = list(inputs)
    if octaves > 0:
        mod = nn.SinEncode(octaves) if kind == "sin" else nn.TriEncode(octaves)
        out += list(mod(nn.CoopVec(*inputs)))
    return out
