"""Small Dr.Jit neural networks: encodings, packed MLPs and the EM-feature network.

Everything here is part of one Dr.Jit AD graph with the splatting kernels. The MLPs run as
cooperative vectors (``drjit.nn``); on the LLVM backend the EM network's matrix products run on
the host's BLAS inside a custom AD op instead (:class:`_HostMLP` per MLP, :class:`_HostEMNet` for
the whole EM network; :attr:`NetConfig.host_products`), because the cooperative-vector backward
there adds weight gradients atomically (a Stage-1 splat step at batch 4 and 10 000 Gaussians:
354 -> 194 ms of kernel time, plus about 70 ms of host products). The host passes' element-wise
steps are fused loops (:mod:`rfmitsuba.models.host_loops`).

The EM-feature network of a Gaussian field maps (Gaussian position, antenna
position[, extra inputs such as a person position]) to each Gaussian's signal and
attenuation *per view*. It is factorised so that the cost of the wide layers is
paid once per Gaussian and once per view, and only a small head runs on the
B*N (view, Gaussian) pairs::

    g_i = MLP_g(enc(p_i))                  # N evaluations
    a_b = MLP_a(enc(q_b), extra_b)         # B evaluations
    (s, d)_{b,i} = head(act(g_i + a_b))    # B*N evaluations (view-major, b*N + i)

``g_i + a_b`` is exactly a first linear layer on the concatenated inputs, so the
network is an ordinary MLP on ``[enc(p_i), enc(q_b), extra_b]``.
"""
from __future__ import annotations

import dataclasses
from collections import OrderedDict
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ..core import backend as B
from ..core.errors import ConfigError
from ..core.host_threads import Buffers
from ..core.host_threads import host_threads as _host_threads
from ..core.host_threads import lane_pool as _lane_pool
from ..core.upload import empty_aligned, upload, upload_rows, zeros_aligned
from . import host_loops


@dataclass
class NetConfig:
    """Architecture of the EM-feature network.

    encoding: positional encoding of the Gaussian position, "sin" (NeRF-style sines), "tri"
        (triangle waves) or "hashgrid" (multiresolution hash grid, Instant-NGP style).
    gaussian_octaves / antenna_octaves: octaves of the sine/triangle encodings (0 = raw input only).
    width: hidden width of every layer; branch_layers: hidden layers of each branch;
    head_layers: hidden layers of the head that runs on every (view, Gaussian) pair.
    hash_*: hash-grid settings (levels, features per level, log2 table size, coarsest
        resolution, growth factor between levels); only used with encoding="hashgrid".
    signal_bias: initial bias of the signal output (signal = sigmoid(out)), so training
        starts from a dim field.
    host_products: on the LLVM backend, run the MLPs' matrix products on the host's BLAS
        (:class:`MLP`); False: Dr.Jit cooperative vectors, as on CUDA. Same values and
        gradients; ``rfmitsuba bench splat`` times a Stage-1 step both ways.
    precision: number format of the cooperative-vector products, "auto" (half on CUDA, where
        Dr.Jit 1.5 packs only half-precision matrices; single on LLVM), "single" or "half"
        (float16 products and inputs, float32 master weights: :class:`MLP`).
    """

    encoding: Literal["sin", "tri", "hashgrid"] = "sin"
    gaussian_octaves: int = 6
    antenna_octaves: int = 6
    width: int = 64
    branch_layers: int = 1
    head_layers: int = 1
    hash_levels: int = 8
    hash_features: int = 2
    hash_log2_size: int = 14
    hash_base_resolution: int = 4
    hash_per_level_scale: float = 1.6
    signal_bias: float = -2.0
    host_products: bool = True
    precision: Literal["auto", "single", "half"] = "auto"

    def __post_init__(self) -> None:
        if self.precision not in PRECISIONS:
            raise ConfigError(f"NetConfig.precision must be one of {', '.join(PRECISIONS)}, got {self.precision!r}")
        for name in ("gaussian_octaves", "antenna_octaves", "branch_layers", "head_layers"):
            if getattr(self, name) < 0:
                raise ConfigError(f"NetConfig.{name} must be >= 0, got {getattr(self, name)}")
        if self.width < 1:
            raise ConfigError(f"NetConfig.width must be >= 1, got {self.width}")
        if self.encoding == "hashgrid" and (self.hash_levels < 1 or self.hash_features < 1):
            raise ConfigError("NetConfig: hash_levels and hash_features must be >= 1")


#: Number formats of :class:`MLP`'s products ("auto": :func:`resolve_precision`).
PRECISIONS = ("auto", "single", "half")


def resolve_precision(precision: str = "auto") -> str:
    """The number format an :class:`MLP` runs in: "auto" is "half" on CUDA and "single" on LLVM.

    Raises:
        ConfigError: an unknown name, or "single" on CUDA (Dr.Jit 1.5 converts only half-precision
            matrices to the layout its CUDA cooperative vectors need for training).
    """
    if precision not in PRECISIONS:
        raise ConfigError(f"MLP precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if precision == "auto":
        return "half" if B.is_cuda() else "single"
    if precision == "single" and B.is_cuda():
        raise ConfigError("MLP precision 'single' is not available on CUDA: Dr.Jit 1.5 packs only half-precision "
                          "matrices for cooperative vectors there; use 'half' or 'auto'")
    return precision


def _tensor_type(*, half: bool = False):
    return B.ensure().TensorXf16 if half else B.ensure().TensorXf


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


#: rows per block of :class:`_HostPass`: each block runs through every layer before the next, so
#: its activations stay in the cache (64 features x 2048 rows = 512 KiB per layer). The splat
#: field's head alone (64 -> 64 -> 3 on 40 000 rows, forward and backward) took 61-67 ms in
#: blocks of 1024-2048 rows against 106-112 ms in one piece, with other processes on both cores;
#: a whole Stage-1 splat step (10 000 Gaussians, batch 4, 45 x 180, one Dr.Jit thread beside one
#: busy core) 298-301 ms against 304-309 ms.
HOST_BLOCK_ROWS = 2048

#: lanes of a :class:`_HostPass`: its rows (items) are cut into this many contiguous ranges, each
#: with its own gradient accumulators, added in lane order at the end. The lanes run on as many
#: host threads as Dr.Jit has (:func:`drjit.thread_count`, at most this many), and the result is
#: the same bits whichever number ran them (tests/models/test_nn.py).
HOST_LANES = 2

#: fewer rows than this (items x views) run as one lane on the calling thread: below it a second
#: thread's start-up costs more than it saves
HOST_THREAD_MIN_ROWS = 8192


#: the host arrays behind :class:`_HostMLP`'s latest uploads (its outputs and input gradients):
#: the columns' JIT indices -> (host array [M, D], the columns, which hold those indices). The
#: next op reads a hit from here instead of evaluating the columns, copying them back and
#: stacking them: the EM network's trunk -> head in the forward pass, head -> trunk in the
#: backward pass (10 000 Gaussians x 64 features). The columns are kept alive with their array,
#: so their indices cannot be reused for other arrays while an entry exists.
_UPLOADED: OrderedDict = OrderedDict()
_UPLOADED_MAX = 8


def _upload_kept(array_type, values: np.ndarray) -> list:
    """:func:`rfmitsuba.core.upload.upload_rows` (Dr.Jit borrows ``values``, which nobody
    writes afterwards), remembering ``values`` for :func:`_host_columns`."""
    cols = upload_rows(array_type, values)
    key = tuple(c.index for c in cols)
    _UPLOADED[key] = (values, cols)
    _UPLOADED.move_to_end(key)
    while len(_UPLOADED) > _UPLOADED_MAX:
        _UPLOADED.popitem(last=False)
    return cols


def _kept(values: list) -> np.ndarray | None:
    """The host array that D ``Float`` [M] were uploaded from, when they are the columns of a
    recent :func:`_upload_kept` (read only), else None."""
    hit = _UPLOADED.get(tuple(v.index for v in values))
    return None if hit is None else hit[0]


def _host_columns(groups: list) -> list:
    """Lists of D ``Float`` [M] -> float32 [M, D] host arrays (read only), one per list: the
    array a list was uploaded from when it is the columns of a recent :func:`_upload_kept`
    (nothing runs), otherwise the list evaluated (one kernel for all such lists; the call waits
    for it) and stacked (an F-ordered array). An empty list gives None."""
    import drjit as dr

    found = [_kept(g) if g else None for g in groups]
    missing = [g for g, f in zip(groups, found) if g and f is None]
    if missing:
        dr.eval(missing)
    # a miss is stacked column by column into a [D, M] array and read through its transpose (an
    # F-ordered [M, D] view, which the host's matrix products take as it is): 39 columns of 10 000
    # took 0.09 ms against 0.37 ms when written row by row
    return [None if not g else f if f is not None else np.stack([np.asarray(v.numpy(), np.float32) for v in g]).T
            for g, f in zip(groups, found)]


#: activations of the :class:`_HostPass` objects alive, and every lane's scratch arrays
_BUFFERS = Buffers()


class _HostPass:
    """One call of an MLP on host arrays (plain NumPy): its forward pass, then once its backward
    pass, with the activations kept in between. :class:`_HostMLP` is the Dr.Jit op around it.

    Args:
        x: float32 [N, D] inputs (read only); ``y``: float32 [B, D] per-view inputs or None.
            With ``y`` the rows are the (view, item) pairs ``act(x_i + y_b)``, view-major
            (``b * N + i``).
        weights: float32 [size] packed weights; ``layers``: (weight offset, out, in, row
            stride, bias offset) per linear layer (:attr:`MLP._host_layers`).
        threads: host threads to run the lanes on (1: all on the caller's thread).

    The items are cut into :data:`HOST_LANES` contiguous ranges (lanes) and each range into
    blocks of at most :data:`HOST_BLOCK_ROWS` rows that run through every layer before the next
    block; a lane's weight and per-view gradients are summed in its own arrays and the lanes'
    sums added in order, so the bits do not depend on ``threads``. Arrays come from and go back
    to :data:`_BUFFERS`: :meth:`release` when the backward pass has run (or when no backward
    pass will).
    """

    def __init__(self, x: np.ndarray, y: np.ndarray | None, weights: np.ndarray, layers: tuple, *,
                 threads: int = 1):
        self.x, self.y, self.layers = x, y, layers
        self.size = weights.shape[0]
        self.n = x.shape[0]
        block = min(max(1, int(HOST_BLOCK_ROWS)), max(self.n, 1))
        # per layer: (W^T contiguous [in, out] for the forward, W [out, in], b [out], and for the
        # output layer b tiled [block, out]): the output layer's bias is added as a whole block
        # (one flat loop; a broadcast row takes one loop per row, 2048 x 64: 17 against 31 us),
        # a hidden layer's with its LeakyReLU in one fused pass (:func:`host_loops.add_leaky`)
        self.mats = []
        for li, (wo, n_out, n_in, st, bo) in enumerate(layers):
            w = weights[wo:wo + n_out * st].reshape(n_out, st)[:, :n_in]
            bias = np.ascontiguousarray(weights[bo:bo + n_out])
            self.mats.append((np.ascontiguousarray(w.T), np.ascontiguousarray(w), bias,
                              np.tile(bias, (block, 1)) if li == len(layers) - 1 else None))
        #: the output layer's bias gradient as a product ``ones @ dz`` (BLAS: 7 against 40 us for
        #: ``dz.sum(axis=0)`` on 2048 x 64); the other column sums come with the LeakyReLU's
        #: derivative (:func:`host_loops.leaky_grad`)
        self.ones = np.ones(block, np.float32)
        self.views = y.shape[0] if y is not None else 1
        rows = self.views * self.n
        lanes = HOST_LANES if rows >= HOST_THREAD_MIN_ROWS else 1
        self.threads = max(1, min(int(threads), lanes))
        cut = [self.n * k // lanes for k in range(lanes + 1)]
        step = max(1, int(HOST_BLOCK_ROWS))
        #: per lane: its (view, first item, end item) blocks, views innermost, so a block's
        #: inputs and input gradients stay in the cache across the views (the splat head, 4 x
        #: 10 000 rows: forward 4.49-4.58 -> 4.30-4.47 ms, backward 8.50-8.55 -> 8.20-8.43 ms)
        self.lanes = [[(b, lo, min(lo + step, cut[k + 1])) for lo in range(cut[k], cut[k + 1], step)
                       for b in range(self.views)] for k in range(lanes)]
        self.width = max(max(n_out, n_in) for _, n_out, n_in, _, _ in layers)
        #: input of every linear layer over all rows: layer 0's is ``x`` itself without ``y``
        self.acts = [x if (li == 0 and y is None) else _BUFFERS.take((rows, n_in))
                     for li, (_, _, n_in, _, _) in enumerate(layers)]

    def _run(self, fn):
        """``fn(lane)`` for every lane (lanes 1.. on the pool's threads when ``threads > 1``);
        their results in lane order."""
        if self.threads == 1 or len(self.lanes) == 1:
            return [fn(k) for k in range(len(self.lanes))]
        pool = _lane_pool()
        futures = [pool.submit(fn, k) for k in range(1, len(self.lanes))]
        first = fn(0)
        return [first] + [f.result() for f in futures]

    def _scratch(self, count: int) -> list:
        return [_BUFFERS.take((min(HOST_BLOCK_ROWS, max(self.n, 1)), self.width)) for _ in range(count)]

    def forward(self, out: np.ndarray) -> np.ndarray:
        """Fill ``out`` float32 [rows, n_out] with the network's outputs; returns it."""
        last = len(self.mats) - 1

        def lane(k):
            z, = self._scratch(1)
            try:
                for b, lo, hi in self.lanes[k]:
                    r0, r1, r = b * self.n + lo, b * self.n + hi, hi - lo
                    if self.y is not None:
                        h = host_loops.add_leaky(self.x[lo:hi], self.y[b], self.acts[0][r0:r1])
                    else:
                        h = self.x[lo:hi]
                    for li, (wt, _, bias, bias_block) in enumerate(self.mats):
                        if li == last:
                            zz = np.matmul(h, wt, out=out[r0:r1])
                            zz += bias_block[:r]
                        else:
                            zz = np.matmul(h, wt, out=z[:r, :wt.shape[1]])
                            h = host_loops.add_leaky(zz, bias, self.acts[li + 1][r0:r1])
            finally:
                _BUFFERS.give([z])

        self._run(lane)
        return out

    def backward(self, dz_all: np.ndarray) -> tuple:
        """Gradients from the outputs' gradients ``dz_all`` float32 [rows, n_out] (read only):
        (weights float32 [size], x float32 [N, D], y float32 [B, D] or None)."""
        if self.acts is None:
            raise RuntimeError("HostMLP: the backward pass ran already (its activations are released)")
        gx = zeros_aligned(self.x.shape)          # uploaded as is (:func:`_upload_kept`)
        pairs = self.y is not None
        last = len(self.layers) - 1

        def lane(k):
            gw = np.zeros(self.size, np.float32)
            gy = zeros_aligned(self.y.shape) if pairs else None
            d0, d1 = self._scratch(2)
            try:
                for b, lo, hi in self.lanes[k]:
                    r0, r1, r = b * self.n + lo, b * self.n + hi, hi - lo
                    dz = dz_all[r0:r1]
                    for li in range(last, -1, -1):
                        wo, n_out, n_in, st, bo = self.layers[li]
                        a = self.acts[li][r0:r1]
                        gw[wo:wo + n_out * st].reshape(n_out, st)[:, :n_in] += dz.T @ a
                        if li == last:
                            gw[bo:bo + n_out] += self.ones[:r] @ dz
                        # the two scratch arrays take turns (layer li's output gradient is read here)
                        nxt = np.matmul(dz, self.mats[li][1], out=(d0, d1)[li % 2][:r, :n_in])
                        if li > 0:
                            # through the LeakyReLU that made layer li's input; the column sums
                            # are the previous layer's bias gradient
                            _, p_out, _, _, p_bo = self.layers[li - 1]
                            host_loops.leaky_grad(nxt, a, colsum=gw[p_bo:p_bo + p_out])
                        elif pairs:
                            # LeakyReLU(x_i + y_b): the rows' gradients go to x_i, their sum to y_b
                            host_loops.leaky_grad(nxt, a, colsum=gy[b], acc=gx[lo:hi])
                        else:
                            gx[lo:hi] += nxt
                        dz = nxt
            finally:
                _BUFFERS.give([d0, d1])
            return gw, gy

        parts = self._run(lane)
        gw, gy = parts[0]
        for gw_k, gy_k in parts[1:]:
            gw += gw_k
            if pairs:
                gy += gy_k
        self.release()
        return gw, gx, gy

    def release(self) -> None:
        """Hand the activations back to :data:`_BUFFERS` (once)."""
        if self.acts is not None:
            _BUFFERS.give([a for a in self.acts if a is not self.x])
            self.acts = None

    def __del__(self):
        self.release()


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


class _HostMLP:
    """An MLP's forward and backward as host matrix products (NumPy BLAS), for the LLVM backend:
    a ``dr.CustomOp`` on (inputs, per-view inputs, packed weights) around a :class:`_HostPass`;
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
        return _host_op("HostMLP", _HostMLP._eval, _HostMLP._backward)

    # eval and backward of the op (``op`` is the CustomOp instance)
    @staticmethod
    def _eval(op, xs, ys, weights, layers):
        import drjit as dr

        xs, ys = [dr.detach(v) for v in xs], [dr.detach(v) for v in ys]
        x, y = _host_columns([xs, ys])                    # one kernel for the inputs not kept
        op.host = _HostPass(x, y, dr.detach(weights).numpy(), layers, threads=dr.thread_count())
        with _host_threads(op.host.threads):
            out = op.host.forward(empty_aligned((op.host.views * op.host.n, layers[-1][1])))
        op.pairs = bool(ys)
        return _upload_kept(type(weights), out)   # aligned: no recompilation downstream

    @staticmethod
    def _backward(op):
        go = list(op.grad_out())
        Float = type(go[0])
        dz, = _host_columns([go])                          # waits for the gradients
        with _host_threads(op.host.threads):
            gw, gx, gy = op.host.backward(dz)
        op.set_grad_in("weights", upload(Float, gw))
        if op.pairs:
            op.set_grad_in("ys", _upload_kept(Float, gy))
        op.set_grad_in("xs", _upload_kept(Float, gx))


class _HostEMNet:
    """The whole EM-feature network on the host as one ``dr.CustomOp`` (LLVM backend, every MLP
    with host products, no hash grid): the Gaussian branch on the encoded positions, the antenna
    branch on the encoded antenna inputs and the head on every (view, Gaussian) pair, three
    :class:`_HostPass` objects run one after the other in one host section, and their backward
    passes in reverse order.

    Values and gradients are those of the three :class:`_HostMLP` ops in a row (the same host
    arithmetic, bit for bit: tests/models/test_nn.py); what goes is the traffic between them:
    the branches' outputs uploaded to Dr.Jit and read back by the head, two more ops in the AD
    graph and two more cuts of Dr.Jit's pool: a Stage-1 splat step's timeline (10 000 Gaussians,
    batch 4, 90 x 360, median of 90 steps) 46.7 -> 43.8 ms."""

    @staticmethod
    def op():
        """The ``dr.CustomOp`` class (made once)."""
        return _host_op("HostEMNet", _HostEMNet._eval, _HostEMNet._backward)

    @staticmethod
    def _eval(op, xs, ants, w_gaussian, w_antenna, w_head, layers):
        import drjit as dr

        xs, ants = [dr.detach(v) for v in xs], [dr.detach(v) for v in ants]
        x, a = _host_columns([xs, ants])
        lg, la, lh = layers
        threads = dr.thread_count()
        # the branches' outputs: the head's inputs, filled before it runs
        g, y = empty_aligned((x.shape[0], lg[-1][1])), empty_aligned((a.shape[0], la[-1][1]))
        op.passes = (_HostPass(x, None, dr.detach(w_gaussian).numpy(), lg, threads=threads),
                     _HostPass(a, None, dr.detach(w_antenna).numpy(), la, threads=threads),
                     _HostPass(g, y, dr.detach(w_head).numpy(), lh, threads=threads))
        pg, pa, ph = op.passes
        with _host_threads(max(p.threads for p in op.passes)):
            pg.forward(g)
            pa.forward(y)
            out = ph.forward(empty_aligned((ph.views * ph.n, lh[-1][1])))
        op.ants_grad = any(dr.grad_enabled(v) for v in ants)
        return _upload_kept(type(w_head), out)

    @staticmethod
    def _backward(op):
        go = list(op.grad_out())
        Float = type(go[0])
        dz, = _host_columns([go])                          # waits for the gradients
        pg, pa, ph = op.passes
        with _host_threads(max(p.threads for p in op.passes)):
            gw_head, g_g, g_y = ph.backward(dz)
            gw_antenna, g_a, _ = pa.backward(g_y)
            gw_gaussian, g_x, _ = pg.backward(g_g)
        op.set_grad_in("w_head", upload(Float, gw_head))
        op.set_grad_in("w_antenna", upload(Float, gw_antenna))
        op.set_grad_in("w_gaussian", upload(Float, gw_gaussian))
        op.set_grad_in("xs", _upload_kept(Float, g_x))
        if op.ants_grad:
            op.set_grad_in("ants", _upload_kept(Float, g_a))
        op.passes = None


class MLP:
    """A fully connected network stored as one packed weight buffer.

    Layers: ``n_in -> width (x layers, activation) -> n_out``, LeakyReLU(0.01) between
    layers, linear output. Weights are Xavier-uniform from a seeded Dr.Jit generator,
    so equal ``seed`` gives equal weights; ``zero_output`` zeroes the last layer's weights
    (the network starts as the constant ``out_bias``).

    The single parameter is :attr:`weights` (``Float`` [num_parameters]); assign a new
    value with :meth:`set_weights` (e.g. the optimizer's copy) before evaluating.

    With ``host=True`` on the LLVM backend the products run on the host's BLAS
    (:class:`_HostMLP`, a custom AD op: weight gradients as one product instead of atomic
    adds); otherwise (the default, and always on CUDA) as Dr.Jit cooperative vectors. Both give
    the same values and gradients (tests/models/test_nn.py). ``precision="half"`` (the default on
    CUDA, where Dr.Jit 1.5 packs only half-precision matrices for training) keeps float32
    master weights as :attr:`weights` and runs the products on float16 copies of weights and
    inputs (outputs back in float32; gradients flow to the master through the casts); outputs
    and gradients agree with single precision within 2% of their largest value
    (test_half_precision_matches_single). The host pays off for the splat
    field's EM network (40 000 rows per call; :attr:`NetConfig.host_products`), not for small
    networks called often: the coherent model's gain network trained its test run in 52-57 s on
    the host against 34 s as cooperative vectors.
    """

    def __init__(self, n_in: int, n_out: int, *, width: int, layers: int, seed: int,
                 out_bias: list[float] | None = None, input_layer: bool = True, zero_output: bool = False,
                 host: bool = False, precision: str = "auto"):
        import drjit as dr
        import drjit.nn as nn

        self.n_in, self.n_out = n_in, n_out
        #: "single" or "half" (:func:`resolve_precision`)
        self.precision = resolve_precision(precision)
        half = self.precision == "half"
        mods = []
        for _ in range(layers):
            mods += [nn.Linear(-1, width), nn.LeakyReLU(0.01)]
        mods.append(nn.Linear(-1, n_out))
        tensor = _tensor_type(half=half)
        net = nn.Sequential(*mods).alloc(tensor, n_in, rng=dr.rng(seed=int(seed) + 0x1000))
        if out_bias is not None:
            net.layers[-1].bias = tensor(np.asarray(out_bias, dtype=np.float16 if half else np.float32))
        if zero_output:  # the network starts as the constant out_bias (its last layer learns first)
            net.layers[-1].weights = dr.zeros(tensor, net.layers[-1].weights.shape)
        self._num_parameters = sum(int(np.prod(m.weights.shape)) + int(m.bias.shape[0])
                                   for m in net.layers if isinstance(m, nn.Linear))
        self.net = nn.pack(net, layout="training")
        #: half precision: the float32 master copy of the packed buffer (the trainable parameter)
        self._master = None
        if half:
            self._master = B.Float(self.net["weights"])
            dr.eval(self._master)
        #: (weight offset, out, in, row stride, bias offset) per linear layer where host matrix
        #: products run this network (:class:`_HostMLP`: LLVM backend, ``host``), else None
        self._host_layers = None
        if host and not B.is_cuda() and not half:
            lin = [m for m in self.net.layers if isinstance(m, nn.Linear)]
            self._host_layers = tuple((int(m.weights.offset), int(m.weights.shape[0]), int(m.weights.shape[1]),
                                       int(m.weights.stride), int(m.bias.offset)) for m in lin)

    @property
    def weights(self):
        """The packed weights and biases: ``Float`` [buffer_size] (float32 in either precision)."""
        return self._master if self._master is not None else self.net["weights"]

    def set_weights(self, value) -> None:
        """Replace the weights (``Float`` or float32 numpy [buffer_size]); keeps AD links."""
        n = self.buffer_size
        if isinstance(value, np.ndarray):
            if value.shape != (n,):
                raise ConfigError(f"MLP weights: expected shape ({n},), got {value.shape}")
            value = B.Float(value.astype(np.float32))
        import drjit as dr

        if self._master is not None:
            self._master = value
            dr.eval(self._master)
            return
        self.net["weights"] = value
        dr.eval(self.net["weights"])  # flush the in-place copy before any kernel reads it

    @property
    def num_parameters(self) -> int:
        """Trainable scalars: every layer's weights and biases (the buffer's padding not counted)."""
        return self._num_parameters

    @property
    def buffer_size(self) -> int:
        """Length of :attr:`weights`, the packed buffer: :attr:`num_parameters` on LLVM, more on
        CUDA, whose training-optimal layout pads the matrices."""
        return int(self.weights.shape[0])

    def _cast_master(self, *, detach: bool = False) -> None:
        """Half precision: put the float16 copy of the float32 master weights into the packed
        network (a differentiable cast, so gradients reach the master, unless ``detach``)."""
        import drjit as dr

        self.net["weights"] = B.ensure().Float16(dr.detach(self._master) if detach else self._master)

    def layer_arrays(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The current weights as ``(W [out, in], b [out])`` float32 arrays per linear layer, read
        back from the packed buffer whatever its layout (row-major on LLVM; on CUDA the
        training-optimal layout is padded and reordered, so :attr:`weights` is no plain matrix);
        in half precision, the float16 values the products use."""
        import drjit.nn as nn

        if self._master is not None:
            self._cast_master(detach=True)
        out = []
        for layer in (m for m in self.net.layers if isinstance(m, nn.Linear)):
            W, b = nn.unpack(layer.weights, layer.bias)
            rows, cols = W.shape
            wbuf = np.asarray(W.buffer.numpy(), np.float32)
            bbuf = np.asarray(b.buffer.numpy(), np.float32)
            out.append((wbuf[W.offset:W.offset + rows * W.stride].reshape(rows, W.stride)[:, :cols].copy(),
                        bbuf[b.offset:b.offset + rows].copy()))
        return out

    def __call__(self, inputs: list) -> list:
        """Evaluate on ``inputs``: list of n_in ``Float`` [M] -> list of n_out ``Float`` [M]."""
        import drjit.nn as nn

        if len(inputs) != self.n_in:
            raise ValueError(f"MLP expects {self.n_in} inputs, got {len(inputs)}")
        if self._host_layers is not None:
            import drjit as dr

            return list(dr.custom(_HostMLP.op(), list(inputs), [], self.net["weights"], self._host_layers))
        if self._master is not None:
            self._cast_master()
            out = self.net(nn.CoopVec(*[B.ensure().Float16(x) for x in inputs]))
            return grad_barrier([B.Float(o) for o in out])
        return grad_barrier(list(self.net(nn.CoopVec(*inputs))))

    def pairs(self, per_item: list, per_view: list) -> list:
        """Evaluate on every (view, item) pair: ``MLP(LeakyReLU(per_item_i + per_view_b))``.

        Args:
            per_item: n_in ``Float`` [N]; per_view: n_in ``Float`` [B].
        Returns:
            n_out ``Float`` [B*N], view-major (``b * N + i``).
        """
        import drjit as dr

        if len(per_item) != self.n_in or len(per_view) != self.n_in:
            raise ValueError(f"MLP.pairs expects {self.n_in} inputs per item and per view, "
                             f"got {len(per_item)} and {len(per_view)}")
        if self._host_layers is not None:
            return list(dr.custom(_HostMLP.op(), list(per_item), list(per_view), self.net["weights"],
                                  self._host_layers))
        n, b = dr.width(per_item[0]), dr.width(per_view[0])
        idx = dr.arange(B.UInt32, n * b)
        n_op = dr.opaque(B.UInt32, n)  # opaque: a new N must not trigger a kernel recompilation
        gi, bi = idx % n_op, idx // n_op
        h = [dr.gather(B.Float, gg, gi) + dr.gather(B.Float, aa, bi) for gg, aa in zip(per_item, per_view)]
        return self([dr.maximum(x, 0) + 0.01 * dr.minimum(x, 0) for x in h])


class HashGrid:
    """A 3-D multiresolution hash-grid encoding (``drjit.nn.HashGridEncoding``) with one
    parameter array :attr:`weights` (``Float`` [num_parameters]); inputs in [0, 1]^3."""

    def __init__(self, cfg: NetConfig, *, seed: int):
        import drjit as dr
        from drjit.hashgrid import HashGridEncoding

        self.enc = HashGridEncoding(
            B.Float, 3, n_levels=cfg.hash_levels, n_features_per_level=cfg.hash_features,
            hashmap_size=2 ** cfg.hash_log2_size, base_resolution=cfg.hash_base_resolution,
            per_level_scale=cfg.hash_per_level_scale, rng=dr.rng(seed=int(seed) + 0x2000))
        self.n_out = cfg.hash_levels * cfg.hash_features

    @property
    def weights(self):
        return self.enc.data

    def set_weights(self, value) -> None:
        if isinstance(value, np.ndarray):
            value = B.Float(value.astype(np.float32))
        self.enc.data = value

    @property
    def num_parameters(self) -> int:
        return int(self.enc.n_params)

    #: Length of :attr:`weights` (no padding in a hash table).
    buffer_size = num_parameters

    def __call__(self, inputs: list) -> list:
        return list(self.enc(inputs))


class EMNetwork:
    """EM-feature network: (Gaussian position, antenna position, extra inputs) ->
    per-view signal, attenuation offset and log-scale offset of every Gaussian.

    Args:
        cfg: architecture.
        extra_inputs: number of extra per-view inputs (0 for the background; 3 for a person
            position in Stage 2), given to :meth:`__call__` already normalised to about [0, 1].
        seed: weight initialisation seed.

    Parameters (see :meth:`parameters`): ``"gaussian"``, ``"antenna"``, ``"head"`` packed MLP
    weights, plus ``"hash"`` for the hash-grid encoding.
    """

    def __init__(self, cfg: NetConfig, *, extra_inputs: int = 0, seed: int = 0):
        self.cfg = cfg
        self.extra_inputs = int(extra_inputs)
        w = cfg.width
        self.hash = HashGrid(cfg, seed=seed) if cfg.encoding == "hashgrid" else None
        n_g = (3 + self.hash.n_out) if self.hash else 3 * (1 + 2 * cfg.gaussian_octaves)
        n_a = 3 * (1 + 2 * cfg.antenna_octaves) + self.extra_inputs
        kw = {"host": cfg.host_products, "precision": cfg.precision}
        self.gaussian = MLP(n_g, w, width=w, layers=cfg.branch_layers, seed=seed + 1, **kw)
        self.antenna = MLP(n_a, w, width=w, layers=cfg.branch_layers, seed=seed + 2, **kw)
        self.head = MLP(w, 3, width=w, layers=cfg.head_layers, seed=seed + 3, out_bias=[cfg.signal_bias, 0.0, 0.0],
                        **kw)

    def modules(self) -> dict:
        """Name -> module (each has ``weights``, ``set_weights``, ``num_parameters``)."""
        mods = {"gaussian": self.gaussian, "antenna": self.antenna, "head": self.head}
        if self.hash is not None:
            mods["hash"] = self.hash
        return mods

    @property
    def num_parameters(self) -> int:
        return sum(m.num_parameters for m in self.modules().values())

    def gaussian_features(self, pos01: list) -> list:
        """Per-Gaussian branch: pos01 list of 3 ``Float`` [N] in [0, 1] -> ``width`` ``Float`` [N]."""
        return self.gaussian(self._gaussian_inputs(pos01))

    def _gaussian_inputs(self, pos01: list) -> list:
        """The Gaussian branch's inputs: the positions and their hash-grid features, or the
        positions' encoding."""
        if self.hash is not None:
            return list(pos01) + self.hash(pos01)
        return encode([p * 0.5 for p in pos01], octaves=self.cfg.gaussian_octaves, kind=self.cfg.encoding)

    def antenna_features(self, ant01: list, extra: list | None = None) -> list:
        """Per-view branch: ant01 list of 3 ``Float`` [B] in [0, 1], extra list of
        ``extra_inputs`` ``Float`` [B] -> ``width`` ``Float`` [B]."""
        return self.antenna(self._antenna_inputs(ant01, extra))

    def _antenna_inputs(self, ant01: list, extra: list | None) -> list:
        """The antenna branch's inputs: the encoded antenna position, then the extra inputs."""
        kind = "tri" if self.cfg.encoding == "tri" else "sin"
        x = encode([a * 0.5 for a in ant01], octaves=self.cfg.antenna_octaves, kind=kind)
        extra = list(extra or [])
        if len(extra) != self.extra_inputs:
            raise ValueError(f"EMNetwork expects {self.extra_inputs} extra inputs, got {len(extra)}")
        return x + extra

    def __call__(self, pos01: list, ant01: list, extra: list | None = None) -> tuple:
        """Signal and attenuation offsets for every (view, Gaussian) pair.

        Args:
            pos01: 3 ``Float`` [N], Gaussian positions mapped into [0, 1] (scene box).
            ant01: 3 ``Float`` [B], antenna positions mapped into [0, 1].
            extra: ``extra_inputs`` ``Float`` [B] or None.

        Returns:
            (signal_logit, attenuation_logit, log_scale_offset): ``Float`` [B*N] each,
            view-major (b*N + i).
        """
        mods = (self.gaussian, self.antenna, self.head)
        if self.hash is None and all(m._host_layers is not None for m in mods):
            # the whole network in one host op (:class:`_HostEMNet`)
            import drjit as dr

            xs = self._gaussian_inputs(pos01)
            ants = self._antenna_inputs(ant01, extra)
            for m, inputs in ((self.gaussian, xs), (self.antenna, ants)):
                if len(inputs) != m.n_in:
                    raise ValueError(f"MLP expects {m.n_in} inputs, got {len(inputs)}")
            out = dr.custom(_HostEMNet.op(), list(xs), list(ants), self.gaussian.weights, self.antenna.weights,
                            self.head.weights, tuple(m._host_layers for m in mods))
            return out[0], out[1], out[2]
        out = self.head.pairs(self.gaussian_features(pos01), self.antenna_features(ant01, extra))
        return out[0], out[1], out[2]


def config_dict(cfg: NetConfig) -> dict:
    """Plain dict of a :class:`NetConfig` (for metadata)."""
    return dataclasses.asdict(cfg)
