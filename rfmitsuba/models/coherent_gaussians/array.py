"""The array model of the coherent Gaussian field: the mutual coupling's pattern, the array's pose
rotation, and the read-out of calibrated channels (amplitude or phase-only Bartlett)."""
from __future__ import annotations


import numpy as np

from ...rf import array as antenna
from ...rf.bartlett import bartlett
from ..base import Views


def coupling_index() -> np.ndarray:
    """Which learned coupling coefficient each entry ``K[m, n]`` of the mutual coupling ``I + K``
    of the 4 x 4 array takes: int64 [16, 16], -1 where ``K[m, n] = 0``.

    A reciprocal coupling (``K = K^T``, as for any passive array) between elements that are row,
    column or diagonal neighbours (42 pairs, 84 parameters); elements farther apart and
    ``K[m, m]`` (a per-element gain, which the calibration already holds) take none.
    """
    M = antenna.NUM_ELEMENTS
    r, c = np.divmod(np.arange(M), antenna.COLS)
    near = (np.abs(r[:, None] - r[None]) <= 1) & (np.abs(c[:, None] - c[None]) <= 1) & ~np.eye(M, dtype=bool)
    out = np.full((M, M), -1, np.int64)
    m, n = np.nonzero(np.triu(near, 1))
    out[m, n] = out[n, m] = np.arange(len(m))
    return out

def coupling_size() -> int:
    """Learned complex coupling coefficients (:func:`coupling_index`): 42."""
    return int(coupling_index().max()) + 1

def _rodrigues(w0, w1, w2, v0, v1, v2):
    """Rotate vectors ``v`` by the rotation vector ``w`` (Dr.Jit arrays, broadcast)."""
    import drjit as dr

    th = dr.sqrt(w0 * w0 + w1 * w1 + w2 * w2 + 1e-24)
    k0, k1, k2 = w0 / th, w1 / th, w2 / th
    c, s = dr.cos(th), dr.sin(th)
    kv = k0 * v0 + k1 * v1 + k2 * v2
    cx0, cx1, cx2 = k1 * v2 - k2 * v1, k2 * v0 - k0 * v2, k0 * v1 - k1 * v0
    return (v0 * c + cx0 * s + k0 * kv * (1 - c), v1 * c + cx1 * s + k1 * kv * (1 - c),
            v2 * c + cx2 * s + k2 * kv * (1 - c))

def summed_channels(fields: list, views: Views) -> tuple:
    """The calibrated channels of ``fields`` (coherent Gaussian family) added: (re, im) ``Float`` [B*16]."""
    hr = hi = None
    for f in fields:
        fr, fi = f.channels(views)
        hr, hi = (fr, fi) if hr is None else (hr + fr, hi + fi)
    return hr, hi

def read_out(h_re, h_im, *, readout: str, frequency_hz: float, height: int, width: int, normalize: bool):
    """PAS of calibrated channels (re, im) ``Float`` [B*16]: the amplitude Bartlett, or for
    ``readout = "phase_only"`` the Bartlett of ``h_m / |h_m|`` (NeRF2's measured spectra):
    ``TensorXf`` [B, height, width], differentiable in the channels.

    With gradients (a training step) the Bartlett op runs its Dr.Jit kernels, which a recorded
    step (:mod:`rfmitsuba.train.frozen_step`) runs too, so a traced step equals its recording bit
    for bit; without (rendering, prediction, validation) its host products
    (:func:`rfmitsuba.rf.bartlett.bartlett`'s ``host``)."""
    import drjit as dr

    if readout == "phase_only":
        mag = dr.sqrt(h_re * h_re + h_im * h_im + 1e-20)
        h_re, h_im = h_re / mag, h_im / mag
    host = False if dr.grad_enabled(h_re, h_im) else None
    return bartlett(h_re, h_im, frequency_hz=frequency_hz, height=height, width=width, normalize=normalize,
                    host=host)
