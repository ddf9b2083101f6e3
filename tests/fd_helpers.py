"""Finite-difference gradient checks for Dr.Jit models (Mitsuba-3 style).

:func:`fd_check` compares the AD gradient of a scalar loss with respect to one flat ``Float``
parameter array with central differences at a few randomly chosen entries.

Float32 on the device sets the rules:

* the loss is given as a list of ``Float`` terms; AD differentiates ``sum(dr.sum(t))``, the
  finite differences sum the terms in float64 on the host (a float32 reduction of a few hundred
  terms of size ~1 alone puts ~1e-3 of noise on a difference quotient with a 1e-3 step);
* the step is a fraction of the parameter's scale (``rel_eps * max(|p_i|, min_scale * rms)``);
* the networks use LeakyReLU and some clamps, so a coordinate can have a kink within a step of
  the base point: an entry whose forward and backward one-sided differences disagree by more
  than ``kink`` (relative) is not smooth at that scale and is replaced by another random entry
  (the decision uses only finite differences, never the AD gradient).
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

#: Multiplies every AD gradient before the comparison. 1 in normal runs; set the environment
#: variable ``RFMITSUBA_FD_AD_SCALE`` to e.g. 2, -1 or 0 to check that the tests fail on a wrong gradient.
AD_SCALE = float(os.environ.get("RFMITSUBA_FD_AD_SCALE", "1"))


@dataclass
class FDResult:
    """AD and central-difference derivatives at the checked entries (float64 arrays)."""

    name: str
    index: np.ndarray
    ad: np.ndarray
    fd: np.ndarray
    eps: np.ndarray
    skipped: list

    @property
    def scale(self) -> float:
        """Largest |finite difference| among the checked entries."""
        return float(np.abs(self.fd).max()) if len(self.fd) else 0.0

    def max_error(self) -> float:
        """Largest |AD - FD| relative to :attr:`scale`."""
        return float(np.abs(self.ad - self.fd).max() / max(self.scale, 1e-30))

    def ok(self, rtol: float, atol: float) -> bool:
        """|AD - FD| <= rtol |FD| + atol * scale at every entry (and the entries are not all flat)."""
        return bool(self.scale > 0 and np.all(np.abs(self.ad - self.fd) <= rtol * np.abs(self.fd) + atol * self.scale))

    def report(self) -> str:
        rows = "\n".join(f"  [{i}] ad={a:+.6e} fd={f:+.6e} eps={e:.1e}"
                         for i, a, f, e in zip(self.index, self.ad, self.fd, self.eps))
        skip = f"\n  skipped (kink within the step): {self.skipped}" if self.skipped else ""
        return f"{self.name}: max |ad - fd| / max|fd| = {self.max_error():.3e} (max|fd| = {self.scale:.3e})\n{rows}{skip}"


def host_copy(x):
    """A Dr.Jit array with its own memory holding the values of ``x`` (no AD link).

    ``type(x)(np.asarray(x.numpy()))`` is *not* a copy on the LLVM backend: ``numpy()`` is a view
    of the device memory and the constructor adopts it, so the "copy" shares memory with ``x``
    and changes when that memory is reused in place (a network's packed weights are, e.g. by
    ``set_weights``). ``np.array(..., copy=True)`` breaks the link.
    """
    return type(x)(np.array(x.numpy(), copy=True))


def total(terms) -> float:
    """float64 host sum of a list of ``Float`` arrays."""
    return float(sum(np.sum(np.array(t.numpy(), np.float64)) for t in terms))


def fd_check(loss, params: dict, name: str, *, count: int = 3, top: int = 3, rel_eps: float = 1e-2,
             min_scale: float = 0.1, kink: float = 0.05, seed: int = 0, ad_scale: float | None = None) -> FDResult:
    """AD gradient vs central differences of ``loss`` with respect to ``params[name]``.

    Args:
        loss: ``params -> list of Float``, the terms of the scalar; it must read every parameter
            from its argument (e.g. ``field.assign(params)`` first).
        params: name -> flat ``Float`` (their values are copied here; nothing keeps an AD link).
        name: the parameter to check.
        count: entries chosen uniformly at random.
        top: more entries chosen at random among the 10 % with the largest |AD gradient| (so that
            a network with many near-zero derivatives is still checked where it matters; a
            scaled or sign-flipped gradient has the same largest entries).
        rel_eps: step = rel_eps * max(|p_i|, min_scale * rms of the array).
        kink: relative disagreement of the one-sided differences above which an entry is
            replaced (see module docstring); at most ``count + top`` replacements.
        seed: entry selection.
        ad_scale: multiplies the AD gradient (default :data:`AD_SCALE`, i.e. 1; other values only to
            check that a wrong gradient fails).
    """
    import drjit as dr

    base = {k: host_copy(v) for k, v in params.items()}
    p = dict(base)
    p[name] = host_copy(base[name])
    dr.enable_grad(p[name])
    terms = loss(p)
    dr.backward(sum(dr.sum(t) for t in terms))
    g = np.array(dr.grad(p[name]).numpy(), np.float64) * (AD_SCALE if ad_scale is None else ad_scale)
    arr = np.array(base[name].numpy(), np.float32)
    rng = np.random.default_rng(seed)
    order = list(rng.permutation(arr.size))
    big = np.argsort(-np.abs(g))[:max(1, arr.size // 10)]
    picks = list(rng.choice(big, size=min(top, big.size), replace=False)) if top else []
    rms = float(np.sqrt(np.mean(arr.astype(np.float64) ** 2))) or 1.0
    index, fd, eps, skipped = [], [], [], []
    want = count + len(picks)
    with dr.suspend_grad():
        f0 = total(loss(base))
        while len(index) < want and len(skipped) <= want and (picks or order):
            i = int(picks.pop(0) if picks else order.pop(0))
            if i in index or i in skipped:
                continue
            h = np.float32(rel_eps * max(abs(float(arr[i])), min_scale * rms))
            plus, minus = arr.copy(), arr.copy()
            plus[i] = arr[i] + h
            minus[i] = arr[i] - h
            fp = total(loss({**base, name: type(base[name])(plus)}))
            fm = total(loss({**base, name: type(base[name])(minus)}))
            fwd = (fp - f0) / (float(plus[i]) - float(arr[i]))
            bwd = (f0 - fm) / (float(arr[i]) - float(minus[i]))
            if abs(fwd - bwd) > kink * max(abs(fwd), abs(bwd)) and abs(fwd - bwd) > 1e-6 * max(abs(f0), 1.0) / h:
                skipped.append(i)
                continue
            index.append(i)
            fd.append((fp - fm) / (float(plus[i]) - float(minus[i])))  # the float32 step actually taken
            eps.append(float(h))
        loss(base)  # leave the model holding the unperturbed values
    index = np.asarray(index, np.int64)
    return FDResult(name, index, g[index], np.asarray(fd), np.asarray(eps), skipped)
