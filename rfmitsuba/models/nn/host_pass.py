"""One MLP call on host arrays (:class:`HostPass`): its forward pass in blocks of rows on
several lanes, then once its backward pass, in plain NumPy (BLAS) and the fused loops of
:mod:`rfmitsuba.models.nn.host_loops`."""
from __future__ import annotations

import numpy as np

from ...core.host_threads import Buffers
from ...core.host_threads import lane_pool as _lane_pool
from ...core.upload import zeros_aligned
from . import host_loops


#: rows per block of :class:`HostPass`: each block runs through every layer before the next, so
#: its activations stay in the cache (64 features x 2048 rows = 512 KiB per layer). The splat
#: field's head alone (64 -> 64 -> 3 on 40 000 rows, forward and backward) took 61-67 ms in
#: blocks of 1024-2048 rows against 106-112 ms in one piece, with other processes on both cores;
#: a whole Stage-1 splat step (10 000 Gaussians, batch 4, 45 x 180, one Dr.Jit thread beside one
#: busy core) 298-301 ms against 304-309 ms.
HOST_BLOCK_ROWS = 2048

#: lanes of a :class:`HostPass`: its rows (items) are cut into this many contiguous ranges, each
#: with its own gradient accumulators, added in lane order at the end. The lanes run on as many
#: host threads as Dr.Jit has (:func:`drjit.thread_count`, at most this many), and the result is
#: the same bits whichever number ran them (tests/models/nn/test_nn_host_pass.py).
HOST_LANES = 2

#: fewer rows than this (items x views) run as one lane on the calling thread: below it a second
#: thread's start-up costs more than it saves
HOST_THREAD_MIN_ROWS = 8192


#: activations of the :class:`HostPass` objects alive, and every lane's scratch arrays
BUFFERS = Buffers()


class HostPass:
    """One call of an MLP on host arrays (plain NumPy): its forward pass, then once its backward
    pass, with the activations kept in between. :class:`HostMLP` is the Dr.Jit op around it.

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
    to :data:`BUFFERS`: :meth:`release` when the backward pass has run (or when no backward
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
        self.acts = [x if (li == 0 and y is None) else BUFFERS.take((rows, n_in))
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
        return [BUFFERS.take((min(HOST_BLOCK_ROWS, max(self.n, 1)), self.width)) for _ in range(count)]

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
                BUFFERS.give([z])

        self._run(lane)
        return out

    def backward(self, dz_all: np.ndarray) -> tuple:
        """Gradients from the outputs' gradients ``dz_all`` float32 [rows, n_out] (read only):
        (weights float32 [size], x float32 [N, D], y float32 [B, D] or None)."""
        if self.acts is None:
            raise RuntimeError("HostMLP: the backward pass ran already (its activations are released)")
        gx = zeros_aligned(self.x.shape)          # uploaded as is (:func:`upload_kept`)
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
                BUFFERS.give([d0, d1])
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
        """Hand the activations back to :data:`BUFFERS` (once)."""
        if self.acts is not None:
            BUFFERS.give([a for a in self.acts if a is not self.x])
            self.acts = None

    def __del__(self):
        self.release()
