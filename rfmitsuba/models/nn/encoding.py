"""The positional encoding of scalar network inputs (NeRF-style sines, ``drjit.nn``)."""
from __future__ import annotations


def encode(inputs: list, *, octaves: int) -> list:
    """Positional encoding of scalar inputs.

    Args:
        inputs: list of D ``Float`` arrays of equal size M, values in about [0, 1].
        octaves: number of frequencies (0 = raw inputs only).

    Returns:
        list of D * (1 + 2 * octaves) ``Float`` arrays of size M: the raw inputs, then
        sin(2 pi 2^k x) and cos(2 pi 2^k x) for k < octaves. The sine encoding has period 1 in x; callers map their inputs into
        [0, 0.5] so that no two points of the domain alias.
    """
    import drjit.nn as nn

    out = list(inputs)
    if octaves > 0:
        out += list(nn.SinEncode(octaves)(nn.CoopVec(*inputs)))
    return out
