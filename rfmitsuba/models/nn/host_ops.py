"""The host passes as Dr.Jit custom AD ops (LLVM backend): one MLP (:class:`HostMLP`) or the
whole EM-feature network (:class:`HostEMNet`) on the host's BLAS, so that weight gradients are
matrix products instead of atomic adds."""
from __future__ import annotations

from ...core.host_threads import host_threads as _host_threads
from ...core.upload import empty_aligned, upload
from .host_columns import host_columns, upload_kept
from .host_pass import HostPass


_HOST_OPS: dict = {}


def _host_op(name: str, eval_fn, backward_fn):
    """A ``dr.CustomOp`` class called ``name``, made once, whose ``eval`` and ``backward`` are
    ``eval_fn(op, ...)`` and ``backward_fn(op)``; forward-mode AD raises (the host passes are
    reverse mode only)."""
    if name not in _HOST_OPS:
        import drjit as dr

        def forward(self):
            raise NotImplementedError(f"{name}: forward-mode AD is not implemented (use reverse mode)")

        _HOST_OPS[name] = type(name, (dr.CustomOp,), {
            "eval": eval_fn, "backward": backward_fn, "forward": forward, "name": lambda self: name})
    return _HOST_OPS[name]


class HostMLP:
    """An MLP's forward and backward as host matrix products (NumPy BLAS), for the LLVM backend:
    a ``dr.CustomOp`` on (inputs, per-view inputs, packed weights) around a :class:`HostPass`;
    the rest of the AD graph is unchanged.

    On the LLVM backend Dr.Jit's cooperative-vector backward adds each weight's gradient with
    one packet reduction and one atomic add per 8-16 input rows: for the splat field's head
    (64 -> 64 -> 3 on 40 000 (view, Gaussian) pairs) that took 166-208 ms of a 580-660 ms
    step. Here a weight's gradient is one product ``dZ^T A`` per block of rows.

    With per-view inputs ``ys`` (:meth:`MLP.pairs`, the EM network's head) the rows are the
    (view, item) pairs, ``act(x_i + y_b)`` for ``xs`` [N] and ``ys`` [B], view-major (``b * N + i``): the
    expansion and its backward (sums over views and over Gaussians) run here too, so no gather
    or atomic scatter is left in the Dr.Jit graph. The host work runs on as many threads as
    Dr.Jit has (:data:`HOST_LANES` at most), with the same bits on any number.
    """

    @staticmethod
    def op():
        """The ``dr.CustomOp`` class (made once)."""
        return _host_op("HostMLP", HostMLP._eval, HostMLP._backward)

    # eval and backward of the op (``op`` is the CustomOp instance)
    @staticmethod
    def _eval(op, xs, ys, weights, layers):
        import drjit as dr

        xs, ys = [dr.detach(v) for v in xs], [dr.detach(v) for v in ys]
        x, y = host_columns([xs, ys])                    # one kernel for the inputs not kept
        op.host = HostPass(x, y, dr.detach(weights).numpy(), layers, threads=dr.thread_count())
        with _host_threads(op.host.threads):
            out = op.host.forward(empty_aligned((op.host.views * op.host.n, layers[-1][1])))
        op.pairs = bool(ys)
        return upload_kept(type(weights), out)   # aligned: no recompilation downstream

    @staticmethod
    def _backward(op):
        go = list(op.grad_out())
        Float = type(go[0])
        dz, = host_columns([go])                          # waits for the gradients
        with _host_threads(op.host.threads):
            gw, gx, gy = op.host.backward(dz)
        op.set_grad_in("weights", upload(Float, gw))
        if op.pairs:
            op.set_grad_in("ys", upload_kept(Float, gy))
        op.set_grad_in("xs", upload_kept(Float, gx))


class HostEMNet:
    """The whole EM-feature network on the host as one ``dr.CustomOp`` (LLVM backend, every MLP
    with host products): the Gaussian branch on the encoded positions, the antenna
    branch on the encoded antenna inputs and the head on every (view, Gaussian) pair, three
    :class:`HostPass` objects run one after the other in one host section, and their backward
    passes in reverse order.

    Values and gradients are those of the three :class:`HostMLP` ops in a row (the same host
    arithmetic, bit for bit: tests/models/nn/test_nn_host_ops.py); what goes is the traffic between them:
    the branches' outputs uploaded to Dr.Jit and read back by the head, two more ops in the AD
    graph and two more cuts of Dr.Jit's pool: a Stage-1 splat step's timeline (10 000 Gaussians,
    batch 4, 90 x 360, median of 90 steps) 46.7 -> 43.8 ms."""

    @staticmethod
    def op():
        """The ``dr.CustomOp`` class (made once)."""
        return _host_op("HostEMNet", HostEMNet._eval, HostEMNet._backward)

    @staticmethod
    def _eval(op, xs, ants, w_gaussian, w_antenna, w_head, layers):
        import drjit as dr

        xs, ants = [dr.detach(v) for v in xs], [dr.detach(v) for v in ants]
        x, a = host_columns([xs, ants])
        lg, la, lh = layers
        threads = dr.thread_count()
        # the branches' outputs: the head's inputs, filled before it runs
        g, y = empty_aligned((x.shape[0], lg[-1][1])), empty_aligned((a.shape[0], la[-1][1]))
        op.passes = (HostPass(x, None, dr.detach(w_gaussian).numpy(), lg, threads=threads),
                     HostPass(a, None, dr.detach(w_antenna).numpy(), la, threads=threads),
                     HostPass(g, y, dr.detach(w_head).numpy(), lh, threads=threads))
        pg, pa, ph = op.passes
        with _host_threads(max(p.threads for p in op.passes)):
            pg.forward(g)
            pa.forward(y)
            out = ph.forward(empty_aligned((ph.views * ph.n, lh[-1][1])))
        op.ants_grad = any(dr.grad_enabled(v) for v in ants)
        return upload_kept(type(w_head), out)

    @staticmethod
    def _backward(op):
        go = list(op.grad_out())
        Float = type(go[0])
        dz, = host_columns([go])                          # waits for the gradients
        pg, pa, ph = op.passes
        with _host_threads(max(p.threads for p in op.passes)):
            gw_head, g_g, g_y = ph.backward(dz)
            gw_antenna, g_a, _ = pa.backward(g_y)
            gw_gaussian, g_x, _ = pg.backward(g_g)
        op.set_grad_in("w_head", upload(Float, gw_head))
        op.set_grad_in("w_antenna", upload(Float, gw_antenna))
        op.set_grad_in("w_gaussian", upload(Float, gw_gaussian))
        op.set_grad_in("xs", upload_kept(Float, g_x))
        if op.ants_grad:
            op.set_grad_in("ants", upload_kept(Float, g_a))
        op.passes = None
