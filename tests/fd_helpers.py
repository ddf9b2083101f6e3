"""Finite-difference gradient checks for Dr.Jit models (Mitsuba-3 style).

:func:`fd_check` compares the AD gradient of a scalar loss with respect to one flat ``Float``
parameter array with central differences at a few randomly chosen entries. Everything is
float32 on the device, so the step is a fraction of the parameter's scale and the comparison
uses a relative tolerance plus an absolute floor tied to the largest difference quotient seen
(float32 rounding of the loss is what limits the difference quotients, not the step).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class FDResult:
    """AD and central-difference derivatives at the checked entries (float64 arrays)."""

    name: str
    index: np.ndarray
    ad: np.ndarray
    fd: np.ndarray
    eps: np.ndarray

    @property
    def scale(self) -> float:
        """Largest |finite difference| among the checked entries."""
        return float(np.abs(self.fd).max())

    def max_error(self) -> float:
        """Largest |AD - FD| relative to :attr:`scale`."""
        return float(np.abs(self.ad - self.fd).max() / max(self.scale, 1e-30))

    def ok(self, rtol: float, atol: float) -> bool:
        """|AD - FD| <= rtol |FD| + atol * scale at every entry (and the entries are not all flat)."""
        return bool(self.scale > 0 and np.all(np.abs(self.ad - self.fd) <= rtol * np.abs(self.fd) + atol * self.scale))

    def report(self) -> str:
        rows = "\n".join(f"  [{i}] ad={a:+.6e} fd={f:+.6e} eps={e:.1e}"
                         for i, a, f, e in zip(self.index, self.ad, self.fd, self.eps))
        return f"{self.name}: max |ad - fd| / max|fd| = {self.max_error():.3e} (max|fd| = {self.scale:.3e})\n{rows}"


def host_copy(x):
    """A Dr.Jit array with its own memory holding the values of ``x`` (detached).

    ``type(x)(np.asarray(x.numpy()))`` is *not* a copy on the LLVM backend: ``numpy()`` is a view
    of the device memory and the constructor adopts it, so the "copy" shares memory with ``x``
    and changes when that memory is reused in place (a network's packed weights are, e.g. by
    ``set_weights`` or the backward pass). ``np.array(..., copy=True)`` breaks the link.
    """
    return type(x)(np.array(x.numpy(), copy=True))


def _value(x) -> float:
    return float(np.asarray(x.numpy(), np.float64).ravel()[0])


def fd_check(loss, params: dict, name: str, *, count: int = 5, rel_eps: float = 1e-2, min_scale: float = 0.1,
             seed: int = 0, index=None, ad_scale: float = 1.0) -> FDResult:
    """AD gradient vs central differences of ``loss`` with respect to ``params[name]``.

    Args:
        loss: ``params -> Float`` of size 1; it must read every parameter from its argument
            (e.g. ``field.assign(params)`` first), so that a perturbed copy takes effect.
        params: name -> flat ``Float`` (detached values; copies are made here).
        name: the parameter to check.
        count: how many entries (chosen at random, without replacement).
        rel_eps: step = rel_eps * max(|p_i|, min_scale * scale of the array), scale = RMS of the array.
        seed: entry selection.
        index: the entries to check instead of random ones.
        ad_scale: multiply the AD gradient (1; other values only to check that a wrong gradient fails).
    """
    import drjit as dr

    base = {k: host_copy(v) for k, v in params.items()}
    p = dict(base)
    p[name] = host_copy(base[name])
    dr.enable_grad(p[name])
    value = loss(p)
    dr.backward(value)
    g = np.array(dr.grad(p[name]).numpy(), np.float64) * ad_scale
    arr = np.array(base[name].numpy(), np.float32)
    if index is None:
        index = np.sort(np.random.default_rng(seed).choice(arr.size, size=min(count, arr.size), replace=False))
    index = np.asarray(index, np.int64)
    rms = float(np.sqrt(np.mean(arr.astype(np.float64) ** 2))) or 1.0
    fd, eps = [], []
    with dr.suspend_grad():
        for i in index:
            h = np.float32(rel_eps * max(abs(float(arr[i])), min_scale * rms))
            plus, minus = arr.copy(), arr.copy()
            plus[i] = arr[i] + h
            minus[i] = arr[i] - h
            step = float(plus[i]) - float(minus[i])  # the float32 step actually taken
            lp = _value(loss({**base, name: type(base[name])(plus)}))
            lm = _value(loss({**base, name: type(base[name])(minus)}))
            fd.append((lp - lm) / step)
            eps.append(h)
        loss(base)  # leave the model holding the unperturbed values
    return FDResult(name, index, g[index], np.asarray(fd), np.asarray(eps))
