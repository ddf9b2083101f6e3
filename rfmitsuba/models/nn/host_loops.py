"""The element-wise steps of the host MLP passes (:class:`rfmitsuba.models.nn.host_pass.HostPass`) as
fused loops, each with its plain NumPy twin.

A host pass runs an MLP block by block (2048 rows of 64 features): a matrix product on the
host's BLAS, then element-wise work on the block (a bias, a LeakyReLU and, in the backward pass,
its derivative and column sums). In NumPy every step is a separate pass over the block with its
own call: 3 passes for ``LeakyReLU(z + b)``, 5 for the derivative, 2 more for the column sums.
Compiled with Numba (``nogil``: the two host threads run them side by side) each is one pass.
On one 2048 x 64 block (one thread, AMD EPYC, AVX-512): ``LeakyReLU(x + y)`` 81 -> 17 us, the
derivative 69 -> 18 us, the derivative with its column sums and an input-gradient addition
113 -> 34 us.

Every loop computes what its twin computes with the same float32 operations in the same
order per element, so values are bit-identical (``tests/models/nn/test_nn_host_loops.py``); column
sums are added row by row here and by a matrix product in the twins (equal up to float32
rounding). Without Numba (it is a dependency, but an environment may lack it) the twins run.
The first call in a process imports Numba and compiles or loads the loops: 0.63 s for
``add_leaky`` and 0.32 s for two signatures of ``leaky_grad`` with an empty cache, 0.42 s and
0.00 s from the cache (which Numba keeps beside this module or in the user's cache folder).

The LeakyReLU's slope is :data:`SLOPE` (0.01, as ``drjit.nn.LeakyReLU(0.01)``); its derivative
is taken from the layer's *output* ``h``: 1 where ``h > 0``, else the slope (a LeakyReLU keeps
the sign of its input).
"""
from __future__ import annotations

import numpy as np

from ...core.compile_once import CompiledOnce

#: Negative slope of the networks' LeakyReLU.
SLOPE = np.float32(0.01)


# ------------------------------------------------------------------------- NumPy twins
def add_leaky_numpy(z: np.ndarray, row: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out = LeakyReLU(z + row)``: z float32 [R, D], row float32 [D] (broadcast over the rows);
    ``out`` float32 [R, D] (may be ``z``). Returns ``out``."""
    np.add(z, row, out=out)
    tmp = np.multiply(out, SLOPE)
    np.maximum(out, tmp, out=out)
    return out


def leaky_grad_numpy(d: np.ndarray, h: np.ndarray, colsum: np.ndarray | None = None,
                     acc: np.ndarray | None = None) -> np.ndarray:
    """``d *= LeakyReLU'`` in place, the derivative taken from the layer's output ``h`` (float32
    [R, D] each); then, where given, ``colsum += d.sum(axis=0)`` (float32 [D]) and ``acc += d``
    (float32 [R, D]). Returns ``d``."""
    slope = (h > 0).astype(np.float32)
    slope *= np.float32(1.0) - SLOPE
    slope += SLOPE
    d *= slope
    if colsum is not None:
        colsum += np.ones(d.shape[0], np.float32) @ d
    if acc is not None:
        acc += d
    return d


# ------------------------------------------------------------------------- fused loops
def _compile():
    """The Numba versions of the loops, or None where Numba cannot be imported."""
    try:
        import numba
    except ImportError:
        return None

    def jit(fn):
        # compiled code is cached beside the module or in the user's cache folder; where neither
        # can be written (a read-only install without a home), Numba refuses to cache, and the
        # loops are compiled in each process instead
        try:
            return numba.njit(nogil=True, cache=True)(fn)
        except RuntimeError:
            return numba.njit(nogil=True, cache=False)(fn)

    @jit
    def add_leaky(z, row, out):
        n, m = z.shape
        for i in range(n):
            for j in range(m):
                t = z[i, j] + row[j]
                out[i, j] = t if t > 0 else SLOPE * t
        return out

    @jit
    def leaky_grad(d, h, colsum, acc):
        # colsum and acc may be None: Numba compiles a version without their branches
        n, m = d.shape
        for i in range(n):
            for j in range(m):
                t = d[i, j] if h[i, j] > 0 else SLOPE * d[i, j]
                d[i, j] = t
                if colsum is not None:
                    colsum[j] += t
                if acc is not None:
                    acc[i, j] += t
        return d

    return add_leaky, leaky_grad


#: the compiled loops (made on first use, from any thread), or None
_loops = CompiledOnce(_compile)


def compiled() -> bool:
    """Whether the fused loops run (Numba present), rather than the NumPy twins."""
    return _loops() is not None


def add_leaky(z: np.ndarray, row: np.ndarray, out: np.ndarray) -> np.ndarray:
    """:func:`add_leaky_numpy` in one pass (float32 arrays; ``out`` may be ``z``)."""
    loops = _loops()
    if loops is None:
        return add_leaky_numpy(z, row, out)
    return loops[0](z, row, out)


def leaky_grad(d: np.ndarray, h: np.ndarray, colsum: np.ndarray | None = None,
               acc: np.ndarray | None = None) -> np.ndarray:
    """:func:`leaky_grad_numpy` in one pass (float32 arrays)."""
    loops = _loops()
    if loops is None:
        return leaky_grad_numpy(d, h, colsum, acc)
    return loops[1](d, h, colsum, acc)
