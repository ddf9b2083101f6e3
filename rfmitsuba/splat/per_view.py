"""One copy of every Gaussian's parameters per view, whose gradient sums the views without atomics.

A batch of B views renders the same N Gaussians B times, so a per-Gaussian array of size N
(means [m], log-scales, rotations, opacity logits) is laid out view-major for the B*N (view,
Gaussian) pairs, entry ``b * N + i`` for Gaussian i in view b. Dr.Jit's own ``gather`` does
this, but its derivative is a scatter-add: on the LLVM backend every pair adds its gradient to
its Gaussian with one atomic per float (a compare-and-swap loop on x86), which took most of the
projection's backward kernel in a Stage-1 splat step (40 000 pairs, 10 floats each). Here the
backward pass is a gather too: one lane per Gaussian sums its B entries in view order (a
symbolic loop over the views, so no kernel holds B or N), and the result does not depend on
thread timing.
"""
from __future__ import annotations

import drjit as dr

from ..core import backend as B


def _repeat(values: list, views: int, n: int) -> list:
    idx = dr.arange(B.UInt32, views * n) % dr.opaque(B.UInt32, n)
    return [dr.gather(type(v), v, idx) for v in values]


class PerView(dr.CustomOp):
    """``dr.custom(PerView, values, views, n)`` -> every array of the list ``values`` repeated
    ``views`` times (entry ``b * n + i`` is ``value[i]``), same types; the gradient of entry i
    is the sum over b. One op for all the arrays of a render: a custom op's output gradients are
    evaluated where the op begins, so one op per array would cut the projection's backward
    kernel into as many kernels, each computing the shared part again."""

    def eval(self, values, views, n):
        self.views, self.n = int(views), int(n)
        return _repeat(values, self.views, self.n)

    def forward(self):
        self.set_grad_out(_repeat(list(self.grad_in("values")), self.views, self.n))

    def backward(self):
        grads = list(self.grad_out())
        dr.eval(grads)    # one kernel (a gather from an unevaluated array evaluates it alone)
        n = dr.opaque(B.UInt32, self.n)
        views = dr.opaque(B.UInt32, self.views)
        i = dr.arange(B.UInt32, self.n)

        def body(b, acc):
            return b + 1, tuple(a + dr.gather(type(g), g, i + b * n) for a, g in zip(acc, grads))

        init = (dr.zeros(B.UInt32, self.n), tuple(dr.zeros(type(g), self.n) for g in grads))
        _, total = dr.while_loop(init, lambda b, acc: b < views, body, labels=("b", "acc"), label="per_view_sum")
        self.set_grad_in("values", list(total))

    def name(self):
        return "splat.PerView"


def per_view(values: list, *, views: int, n: int) -> list:
    """Arrays of width ``n`` (``Float``, ``Array3f``, ``Array4f``) laid out for ``views`` views,
    view-major: width ``views * n``, entry ``b * n + i`` = ``value[i]``, in a list like
    ``values``. Differentiable; the gradient sums each Gaussian's ``views`` entries with gathers,
    in view order (no atomics). ``views == 1`` returns the arrays themselves."""
    values = list(values)
    if views == 1 or not values:
        return values
    return list(dr.custom(PerView, values, int(views), int(n)))
