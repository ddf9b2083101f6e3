"""The element-wise steps of the host Bartlett op (:mod:`rfmitsuba.rf.bartlett_host`) as fused
loops, each with its plain NumPy twin.

Between its matrix products the op walks every pixel of every image: the amplitude
``sqrt(re^2 + im^2)`` of the beam outputs, the min-max normalisation, and in the adjoint the
gradients at the beam outputs. In NumPy each is several passes over ``B x P`` arrays (the
amplitude four, the adjoint's gradients four); compiled with Numba (``nogil``: the host lanes
run them side by side) each is one.

Every loop computes what its twin computes with the same float32 operations in the same order
per element, so values are bit-identical (``tests/rf/test_bartlett_loops.py``). Without Numba
the twins run. Arrays are float32 [B, n] (rows: views; they may be column ranges of wider
arrays), per-row values float32 [B].
"""
from __future__ import annotations

import numpy as np

from ..core.compile_once import CompiledOnce

#: the smallest amplitude an adjoint divides by (as the Dr.Jit kernels of :mod:`rfmitsuba.rf.bartlett`)
TINY = np.float32(1e-30)


# ------------------------------------------------------------------------- NumPy twins
def amplitude_numpy(yr: np.ndarray, yi: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out = sqrt(yr * yr + yi * yi)``. Returns ``out``."""
    np.multiply(yr, yr, out=out)
    out += yi * yi
    return np.sqrt(out, out=out)


def normalized_numpy(p: np.ndarray, lo: np.ndarray, span: np.ndarray, near_lo: np.ndarray, near_hi: np.ndarray,
                     out: np.ndarray, count: np.ndarray) -> np.ndarray:
    """``out = (p - lo) / span`` (``lo``, ``span`` per row), and per row the number of pixels
    with ``p <= near_lo`` and with ``p >= near_hi`` into ``count`` (int64 [B, 2]). Returns ``out``."""
    np.subtract(p, lo[:, None], out=out)
    np.divide(out, span[:, None], out=out)
    count[:, 0] = np.count_nonzero(p <= near_lo[:, None], axis=1)
    count[:, 1] = np.count_nonzero(p >= near_hi[:, None], axis=1)
    return out


def beam_grad_numpy(g: np.ndarray, p: np.ndarray, yr: np.ndarray, yi: np.ndarray, inv: np.ndarray,
                    gyr: np.ndarray, gyi: np.ndarray) -> None:
    """The gradients at the beam outputs from the gradient ``g`` at the images ``p = |y|``:
    ``t = g * inv / max(p, TINY)``, ``gyr = t * yr``, ``gyi = t * yi`` (``inv`` per row: 1 over
    the image's span, or 1 without normalisation)."""
    t = np.multiply(g, inv[:, None])
    t /= np.maximum(p, TINY)
    np.multiply(t, yr, out=gyr)
    np.multiply(t, yi, out=gyi)


def image_sums_numpy(g: np.ndarray, pn: np.ndarray) -> tuple:
    """Per row, ``sum(g * pn)`` and ``sum(g)``: float32 [B] each."""
    return np.einsum("ij,ij->i", g, pn), g.sum(axis=1)


# ------------------------------------------------------------------------- fused loops
def _compile():
    """The Numba versions of the loops, or None where Numba cannot be imported."""
    try:
        import numba
    except ImportError:
        return None

    def jit(fn=None, **options):
        # cached beside the module or in the user's cache folder where either can be written,
        # compiled in each process otherwise. NumPy's error model: a division by zero gives inf
        # as in the twins, and the check Python's model puts before every division keeps the
        # loop from vectorising
        if fn is None:
            return lambda f: jit(f, **options)
        try:
            return numba.njit(nogil=True, cache=True, error_model="numpy", **options)(fn)
        except RuntimeError:
            return numba.njit(nogil=True, cache=False, error_model="numpy", **options)(fn)

    # each loop takes whole C-contiguous arrays and the column range [a, b) to walk, row by row
    # through row slices indexed from 0: a column range passed as its own strided array, or
    # indexed from ``a``, kept the inner loop from vectorising (the amplitude of 8 x 32 400
    # pixels: 0.15-0.19 ms against 0.09 ms); per-row values are read once per row
    @jit
    def amplitude(yr, yi, out, a, b):
        for i in range(yr.shape[0]):
            r, q, o = yr[i, a:b], yi[i, a:b], out[i, a:b]
            for j in range(o.shape[0]):
                o[j] = np.sqrt(r[j] * r[j] + q[j] * q[j])

    @jit
    def normalized(p, lo, span, near_lo, near_hi, out, count, a, b):
        for i in range(p.shape[0]):
            lo_i, span_i, below, above = lo[i], span[i], near_lo[i], near_hi[i]
            r, o = p[i, a:b], out[i, a:b]
            n_lo = n_hi = 0
            for j in range(o.shape[0]):
                v = r[j]
                o[j] = (v - lo_i) / span_i
                n_lo += v <= below
                n_hi += v >= above
            count[i, 0], count[i, 1] = n_lo, n_hi

    @jit
    def beam_grad(g, p, yr, yi, inv, gyr, gyi, a, b):
        for i in range(g.shape[0]):
            inv_i = inv[i]
            gg, pp, r, q, o_r, o_i = g[i, a:b], p[i, a:b], yr[i, a:b], yi[i, a:b], gyr[i], gyi[i]
            for j in range(o_r.shape[0]):
                m = pp[j] if pp[j] > TINY else TINY
                t = (gg[j] * inv_i) / m
                o_r[j] = t * r[j]
                o_i[j] = t * q[j]

    # sums in any order (``reassoc``; no other flag that changes a finite value): float32
    # rounding apart from the twin's, in one pass for both (0.03 ms against 0.08 ms for 8 x 32 400)
    @jit(fastmath={"reassoc", "nnan", "ninf", "nsz"})
    def image_sums(g, pn, s_gpn, s_g, a, b):
        for i in range(g.shape[0]):
            gg, pp = g[i, a:b], pn[i, a:b]
            x = y = np.float32(0.0)
            for j in range(gg.shape[0]):
                x += gg[j] * pp[j]
                y += gg[j]
            s_gpn[i], s_g[i] = x, y

    return amplitude, normalized, beam_grad, image_sums


#: the compiled loops (made on first use, from any thread), or None
_loops = CompiledOnce(_compile)


def compiled() -> bool:
    """Whether the fused loops run (Numba present), rather than the NumPy twins."""
    return _loops() is not None


def amplitude(yr: np.ndarray, yi: np.ndarray, out: np.ndarray, a: int = 0, b: int | None = None) -> None:
    """:func:`amplitude_numpy` on columns ``a:b`` of C-contiguous float32 [B, P] arrays, in one pass."""
    b = yr.shape[1] if b is None else b
    loops = _loops()
    if loops is None:
        amplitude_numpy(yr[:, a:b], yi[:, a:b], out[:, a:b])
    else:
        loops[0](yr, yi, out, a, b)


def normalized(p: np.ndarray, lo: np.ndarray, span: np.ndarray, near_lo: np.ndarray, near_hi: np.ndarray,
               out: np.ndarray, count: np.ndarray, a: int = 0, b: int | None = None) -> None:
    """:func:`normalized_numpy` on columns ``a:b`` of C-contiguous float32 [B, P] arrays, in one
    pass (``count``: int64 [B, 2])."""
    b = p.shape[1] if b is None else b
    loops = _loops()
    if loops is None:
        normalized_numpy(p[:, a:b], lo, span, near_lo, near_hi, out[:, a:b], count)
    else:
        loops[1](p, lo, span, near_lo, near_hi, out, count, a, b)


def beam_grad(g: np.ndarray, p: np.ndarray, yr: np.ndarray, yi: np.ndarray, inv: np.ndarray,
              gyr: np.ndarray, gyi: np.ndarray, a: int = 0, b: int | None = None) -> None:
    """:func:`beam_grad_numpy` on columns ``a:b`` of C-contiguous float32 [B, P] arrays ``g, p,
    yr, yi``, in one pass; ``gyr, gyi``: C-contiguous float32 [B, b - a]."""
    b = g.shape[1] if b is None else b
    loops = _loops()
    if loops is None:
        beam_grad_numpy(g[:, a:b], p[:, a:b], yr[:, a:b], yi[:, a:b], inv, gyr, gyi)
    else:
        loops[2](g, p, yr, yi, inv, gyr, gyi, a, b)


def image_sums(g: np.ndarray, pn: np.ndarray, a: int = 0, b: int | None = None) -> tuple:
    """:func:`image_sums_numpy` on columns ``a:b`` of C-contiguous float32 [B, P] arrays, in one
    pass (equal to the twin's to float32 rounding)."""
    b = g.shape[1] if b is None else b
    loops = _loops()
    if loops is None:
        return image_sums_numpy(g[:, a:b], pn[:, a:b])
    s_gpn, s_g = np.empty(g.shape[0], np.float32), np.empty(g.shape[0], np.float32)
    loops[3](g, pn, s_gpn, s_g, a, b)
    return s_gpn, s_g
