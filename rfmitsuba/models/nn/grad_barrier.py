"""An identity on network outputs that evaluates them, and their gradients in the backward pass
(:func:`grad_barrier`): the guard that Dr.Jit 1.5's cooperative-vector backward needs on LLVM."""
from __future__ import annotations


class _EvalGrad:
    """Identity whose backward pass evaluates the incoming gradients (see :func:`grad_barrier`)."""

    _op = None

    @classmethod
    def op(cls):
        if cls._op is None:
            import drjit as dr

            class EvalGrad(dr.CustomOp):
                def eval(self, xs):
                    out = [dr.detach(x) for x in xs]
                    # One kernel for all outputs: a consumer that gathers from one output
                    # (EMNetwork's pair expansion) would otherwise evaluate it alone, and
                    # every such kernel recomputes the whole network (64 kernels per branch).
                    dr.eval(out)
                    return out

                def forward(self):
                    self.set_grad_out(self.grad_in("xs"))

                def backward(self):
                    g = list(self.grad_out())
                    dr.eval(g)
                    self.set_grad_in("xs", g)

                def name(self):
                    return "EvalGrad"

            cls._op = EvalGrad
        return cls._op


def grad_barrier(values: list) -> list:
    """Identity on a list of ``Float`` arrays that evaluates them (one kernel) and whose
    backward pass evaluates the gradients.

    Dr.Jit 1.5's cooperative-vector backward (LLVM) aborts with "dirty variable" when the
    gradient arriving at a network output was produced by a scatter (a ``gather`` of the
    output, or a rasteriser's atomic accumulation); calling this on the outputs of every
    network avoids it at the cost of one evaluation per network in the backward pass.
    """
    import drjit as dr

    return list(dr.custom(_EvalGrad.op(), list(values)))
