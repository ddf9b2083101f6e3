"""The Bartlett op of :mod:`rfmitsuba.rf.bartlett` on the host (LLVM backend): its two matrix
products on the host's BLAS, its element-wise steps as fused loops
(:mod:`rfmitsuba.rf.bartlett_loops`), inside a ``drjit.CustomOp``. The same images and the
same adjoint as the Dr.Jit kernels, to rounding.

With the channels ``h`` complex [B, 16] (view-major) and the beamformer weights ``W`` complex
[P, 16] of :func:`rfmitsuba.rf.bartlett_ref.beamformer` (``P = height * width`` pixels)::

    forward:  y = h W^T                     [B, 16] x [16, P],   PAS = |y|
    adjoint:  dL/dh = (g / |y| * y) conj(W)  [B, P] x [P, 16]

where ``dL/dh = dL/d(re h) + j dL/d(im h)`` and ``g`` is the gradient at the raw PAS. With
``normalize`` each image is min-max normalised, ``(PAS - lo) / (hi - lo)``, and the gradient also
flows through its minimum and maximum pixels (every pixel that ties), as in the kernels.

The 4 x 4 array is centro-symmetric: element ``15 - m`` sits at ``-r_m``, so its weight is
``conj(W[:, m])``. With ``s_m = h_m + h_{15-m}``, ``d_m = h_m - h_{15-m}`` (m < 8) and
``W[:, m] = a_m + j b_m``::

    re y = sum_m re(s_m) a_m - im(d_m) b_m,      im y = sum_m im(s_m) a_m + re(d_m) b_m,

so both parts of ``y`` are one real product ``[2B, 16] x [16, P]`` with the matrix ``[a; b]``
(float32 [16, P]), and the adjoint one product ``[2B, P] x [P, 16]`` with its transpose: half
the flops of the complex products, on real arrays (:func:`fold`, :func:`unfold`). Measured
(8 views, 90 x 360, one thread): 0.25 ms for the real product against 0.45 ms for the complex
product ``h W^T``.

The pixels are cut into :data:`LANES` contiguous ranges (lanes), each with its own products and
partial sums, added in lane order: the results have the same bits whichever number of threads
ran the lanes (:mod:`rfmitsuba.core.host_threads`; at most as many as Dr.Jit has). The images
handed to Dr.Jit are aligned host arrays it borrows (:mod:`rfmitsuba.core.upload`).

Host code cannot run while a function is recorded (``drjit.freeze``): the recording would keep
the values read back while it was made. :func:`rfmitsuba.rf.bartlett.bartlett` runs its kernels
there and on CUDA.
"""
from __future__ import annotations

import numpy as np

from ..core import backend as B
from ..core.errors import ConfigError
from ..core.host_threads import Buffers, one_blas_thread, run_lanes
from ..core.upload import empty_aligned, upload
from . import bartlett_loops as loops
from . import bartlett_ref as _ref
from .array import NUM_ELEMENTS

#: lanes of a call: its pixels cut into this many contiguous ranges (multiples of 64 pixels)
LANES = 2

#: fewer pixels than this (views x pixels per image) run as one lane
LANE_MIN_PIXELS = 65536

#: host threads the lanes run on, at most (and at most as many as Dr.Jit has). One: on the 2
#: cores beside other load a second one did not pay (8 views, 90 x 360, forward and adjoint:
#: 1.39 ms on one thread, 1.52 ms on two, 3.99 ms on two with Dr.Jit's pool cut to one thread
#: meanwhile as :func:`rfmitsuba.core.host_threads.host_threads` does; one other process busy)
THREADS = 1

#: pixels this close to an image's minimum or maximum, in float32 steps of the image's largest
#: possible amplitude ``sum_m |h_m| / 16``, are close calls: where an image has more than one,
#: their amplitudes are settled in float64 (:meth:`Images.settle`). The products' float32 error
#: is at most about 20 such steps
SETTLE_STEPS = 64

_HALF = NUM_ELEMENTS // 2
_WEIGHTS: dict = {}
_BUFFERS = Buffers()


def weights(*, frequency_hz: float, height: int, width: int) -> tuple:
    """``(A, A^T)``: the real and imaginary parts of the weights of elements 0..7 as the rows of
    float32 [16, P], and its transpose [P, 16], both C-contiguous and read-only; cached per grid.

    Raises ConfigError where the weights are not centro-symmetric (``W[:, 15 - m] = conj(W[:, m])``)."""
    key = (float(frequency_hz), int(height), int(width))
    if key not in _WEIGHTS:
        w = _ref.beamformer(frequency_hz=frequency_hz, resolution_deg=90.0 / height)   # [P, 16]
        if not np.allclose(w[:, ::-1], np.conj(w), rtol=0.0, atol=1e-7):
            raise ConfigError("the host Bartlett products need a centro-symmetric array")
        a = np.ascontiguousarray(np.concatenate([w[:, :_HALF].real.T, w[:, :_HALF].imag.T]), np.float32)
        at = np.ascontiguousarray(a.T)
        a.flags.writeable = at.flags.writeable = False
        _WEIGHTS[key] = (a, at)
    return _WEIGHTS[key]


def fold(h: np.ndarray) -> tuple:
    """Channels complex [B, 16] -> the left factors of the products giving (re y, im y): float32
    [B, 16] each, ``[re s, -im d]`` and ``[im s, re d]``."""
    h = np.asarray(h, np.complex64)
    s, d = h[:, :_HALF] + h[:, :_HALF - 1:-1], h[:, :_HALF] - h[:, :_HALF - 1:-1]
    return (np.ascontiguousarray(np.concatenate([s.real, -d.imag], 1), np.float32),
            np.ascontiguousarray(np.concatenate([s.imag, d.real], 1), np.float32))


def unfold(g_r: np.ndarray, g_i: np.ndarray) -> np.ndarray:
    """The adjoint of :func:`fold`: the gradients at its two factors (float [B, 16] each) -> the
    channels' gradient ``dL/d(re h) + j dL/d(im h)``, complex64 [B, 16]."""
    ds_r, dd_i = g_r[:, :_HALF], -g_r[:, _HALF:]
    ds_i, dd_r = g_i[:, :_HALF], g_i[:, _HALF:]
    out = np.empty((g_r.shape[0], NUM_ELEMENTS), np.complex64)
    out[:, :_HALF] = (ds_r + dd_r) + 1j * (ds_i + dd_i)
    out[:, :_HALF - 1:-1] = (ds_r - dd_r) + 1j * (ds_i - dd_i)
    return out


def lane_cuts(pixels: int, views: int) -> list:
    """The lanes' first pixels and the end: int [lanes + 1]."""
    lanes = LANES if pixels * views >= LANE_MIN_PIXELS and pixels >= 64 * LANES else 1
    return [pixels * k // lanes // 64 * 64 for k in range(lanes)] + [pixels]


class Images:
    """The op's forward pass on host arrays, kept for one adjoint.

    Args:
        h: complex [B, 16] channels (view-major).
        frequency_hz: carrier, Hz; ``height, width``: grid [pixels].
        normalize: min-max normalise each image.
        threads: host threads for the lanes (1: all on the calling thread).
        keep: keep what :meth:`backward` needs (the beam outputs, float32 [2B, P]); False
            hands the scratch back at once.

    Attributes:
        out: float32 [B, P] images (64-byte aligned; Dr.Jit may borrow it: never written again).
    """

    def __init__(self, h: np.ndarray, *, frequency_hz: float, height: int, width: int, normalize: bool,
                 threads: int, keep: bool):
        self.views, self.pixels = np.shape(h)[0], height * width
        self.normalize = bool(normalize)
        self.a, self.at = weights(frequency_hz=frequency_hz, height=height, width=width)
        self.cuts = lane_cuts(self.pixels, self.views)
        lanes = len(self.cuts) - 1
        self.threads = max(1, min(int(threads), lanes))
        left = np.concatenate(fold(h))                           # [2B, 16]
        shape = (self.views, self.pixels)
        # the raw PAS: the output itself, or scratch beside the normalised output
        self.p = _BUFFERS.take(shape) if self.normalize else empty_aligned(shape)
        # the beam outputs, real parts (rows 0..B-1) above imaginary parts: one product of 2B
        # rows runs at 66 GFLOP/s, two of B rows at 40 (8 views, 90 x 360, one thread)
        self.y = _BUFFERS.take((2 * self.views, self.pixels))
        self.yr, self.yi = self.y[:self.views], self.y[self.views:]

        def product(k):
            a, b = self.cuts[k], self.cuts[k + 1]
            np.matmul(left, self.a[:, a:b], out=self.y[:, a:b])
            loops.amplitude(self.yr, self.yi, self.p, a, b)
            return self.p[:, a:b].min(axis=1), self.p[:, a:b].max(axis=1)

        with one_blas_thread():
            ends = run_lanes(product, lanes, threads=self.threads)
            self.lo = np.minimum.reduce([e[0] for e in ends])
            self.hi = np.maximum.reduce([e[1] for e in ends])
        if self.normalize:
            self.out = empty_aligned(shape)
            self._normalize(h, lanes)
        else:
            self.out = self.p
        if not keep:
            self.release()

    def _normalize(self, h: np.ndarray, lanes: int) -> None:
        """:attr:`out` = each image min-max normalised, its extremes settled where they are close
        calls (:meth:`settle`)."""
        # how close to an extreme a pixel's exact amplitude may be while its float32 one is not
        # the extreme: SETTLE_STEPS float32 steps of the image's largest possible amplitude
        self.delta = ((SETTLE_STEPS * np.finfo(np.float32).eps / NUM_ELEMENTS)
                      * np.abs(np.asarray(h, np.complex128)).sum(axis=1))
        self.span = np.maximum(self.hi - self.lo, loops.TINY)
        # float32 thresholds: comparing with float64 ones converted every pixel (4x as long)
        near_lo, near_hi = (self.lo + self.delta).astype(np.float32), (self.hi - self.delta).astype(np.float32)

        def scale(k):
            a, b = self.cuts[k], self.cuts[k + 1]
            count = np.empty((self.views, 2), np.int64)
            loops.normalized(self.p, self.lo, self.span, near_lo, near_hi, self.out, count, a, b)
            return count

        with one_blas_thread():
            #: per image, its pixels near its minimum and near its maximum: int64 [B, 2]; where
            #: both are 1 (the usual case) each extreme is one pixel, the exact one
            self.near = sum(run_lanes(scale, lanes, threads=self.threads))
        close = np.flatnonzero((self.near > 1).any(axis=1))
        if len(close):
            self.settle(h, close)

    def settle(self, h: np.ndarray, rows: np.ndarray) -> None:
        """Images ``rows``: recompute the beam outputs and amplitudes of their pixels near their
        minimum and maximum in float64 from the float32 channels and weights, rounded once,
        then their extremes and normalised images.

        Which pixel is an image's extreme decides where its normalisation's gradient goes, and
        the two largest pixels may differ by less than the products' rounding: by 7.6e-8 of the
        maximum in one of 180 random images (3 views, seed 0), where the folded products made
        the other pixel the larger. Settled, the extreme is the exact one wherever float32 can
        tell the two apart, and ties are exact ties (:meth:`_ties`)."""
        h64 = np.asarray(h, np.complex128)
        p, d = self.p[rows], self.delta[rows, None]
        near = (p >= (self.hi[rows, None] - d).astype(np.float32)) | (p <= (self.lo[rows, None] + d).astype(np.float32))
        k, cols = np.nonzero(near)
        r = rows[k]
        a = self.a[:, cols].astype(np.float64)      # [16, n]
        wr, wi = a[:_HALF], a[_HALF:]
        hr, hi = h64[r].real.T, h64[r].imag.T      # [16, n]
        # y = sum_m h_m w_m over the elements m < 8 and their mirrors 15 - m (weight conj(w_m))
        s_r, s_i = hr[:_HALF] + hr[:_HALF - 1:-1], hi[:_HALF] + hi[:_HALF - 1:-1]
        d_r, d_i = hr[:_HALF] - hr[:_HALF - 1:-1], hi[:_HALF] - hi[:_HALF - 1:-1]
        y_r, y_i = (s_r * wr - d_i * wi).sum(axis=0), (s_i * wr + d_r * wi).sum(axis=0)
        self.yr[r, cols], self.yi[r, cols] = y_r, y_i
        self.p[r, cols] = np.sqrt(y_r * y_r + y_i * y_i)
        # no other pixel can be beyond them: the images' extremes are among these
        p = self.p[rows]
        self.lo[rows], self.hi[rows] = p.min(axis=1), p.max(axis=1)
        self.span[rows] = np.maximum(self.hi[rows] - self.lo[rows], loops.TINY)
        self.out[rows] = (p - self.lo[rows, None]) / self.span[rows, None]

    def backward(self, g: np.ndarray) -> np.ndarray:
        """The channels' gradient of a loss whose gradient at :attr:`out` is ``g`` (float32 [B, P]):
        ``dL/d(re h) + j dL/d(im h)``, complex64 [B, 16]. Once per forward pass."""
        if self.y is None:
            raise RuntimeError("Images.backward: no forward pass kept (keep=False, or backward ran already)")
        g = np.ascontiguousarray(g, np.float32).reshape(self.views, self.pixels)
        lanes = len(self.cuts) - 1
        inv = (np.float32(1.0) / self.span) if self.normalize else np.ones(self.views, np.float32)

        def adjoint(k):
            a, b = self.cuts[k], self.cuts[k + 1]
            gy = _BUFFERS.take((2 * self.views, b - a))
            loops.beam_grad(g, self.p, self.yr, self.yi, inv, gy[:self.views], gy[self.views:], a, b)
            sums = loops.image_sums(g, self.out, a, b) if self.normalize else None
            part = gy @ self.at[a:b]                                 # [2B, P_k] x [P_k, 16]
            _BUFFERS.give([gy])
            return part, sums

        with one_blas_thread():
            parts = run_lanes(adjoint, lanes, threads=self.threads)
        s = parts[0][0]
        for part, _ in parts[1:]:
            s = s + part
        s_r, s_i = s[:self.views], s[self.views:]
        if self.normalize:
            # the gradients at each image's minimum and maximum, (Pn - 1) / span and -Pn / span
            # summed over the image, go to every pixel that ties with them
            s_gpn = sum(part[1][0] for part in parts)
            s_g = sum(part[1][1] for part in parts)
            at_lo, at_hi = (s_gpn - s_g) * inv, -s_gpn * inv
            for rows, cols, d in self._ties(at_lo, at_hi):
                t = d / np.maximum(self.p[rows, cols], loops.TINY)
                np.add.at(s_r, rows, (t * self.yr[rows, cols])[:, None] * self.at[cols])
                np.add.at(s_i, rows, (t * self.yi[rows, cols])[:, None] * self.at[cols])
        self.release()
        return unfold(s_r, s_i)

    def _ties(self, at_lo: np.ndarray, at_hi: np.ndarray) -> list:
        """(rows, pixels, gradient) of every image's pixels equal to its minimum, and of those
        equal to its maximum but not to its minimum."""
        out = []
        for k, (ends, arg, grad) in enumerate(((self.lo, np.argmin, at_lo), (self.hi, np.argmax, at_hi))):
            if (self.near[:, k] == 1).all():   # one pixel near each image's extreme: the usual case
                rows, cols = np.arange(self.views), arg(self.p, axis=1)
            else:
                rows, cols = np.nonzero(self.p == ends[:, None])
            if k == 1:                         # a constant image: its pixels are all at the minimum
                keep = ends[rows] != self.lo[rows]
                rows, cols = rows[keep], cols[keep]
            out.append((rows, cols, grad[rows]))
        return out

    def release(self) -> None:
        """Hand the scratch back (once)."""
        if self.y is not None:
            _BUFFERS.give([self.y] + ([self.p] if self.normalize else []))
            self.y = self.yr = self.yi = None

    def __del__(self):
        self.release()


def _channels(h_re, h_im) -> np.ndarray:
    """Dr.Jit ``Float`` [B*16] real and imaginary parts -> complex64 [B, 16] (evaluated in one kernel)."""
    import drjit as dr

    dr.eval(h_re, h_im)
    re, im = np.asarray(h_re.numpy(), np.float32), np.asarray(h_im.numpy(), np.float32)
    return (re + 1j * im).astype(np.complex64).reshape(-1, NUM_ELEMENTS)


_OP = None


def _op_class():
    global _OP
    if _OP is None:
        import drjit as dr

        class BartlettHost(dr.CustomOp):
            def eval(self, h_re, h_im, frequency_hz, height, width, normalize):
                self.images = Images(_channels(h_re, h_im), frequency_hz=frequency_hz, height=height, width=width,
                                     normalize=normalize, threads=min(THREADS, dr.thread_count()), keep=True)
                return B.Float(self.images.out.reshape(-1))

            def forward(self):
                raise NotImplementedError("BartlettHost supports reverse-mode AD only")

            def backward(self):
                go = self.grad_out()
                dh = self.images.backward(np.asarray(go.numpy(), np.float32))
                self.set_grad_in("h_re", upload(B.Float, dh.real.ravel()))
                self.set_grad_in("h_im", upload(B.Float, dh.imag.ravel()))

            def name(self):
                return "BartlettHost"

        _OP = BartlettHost
    return _OP


def bartlett(h_re, h_im, *, frequency_hz: float, height: int, width: int, normalize: bool):
    """PAS images of B channels on the host, differentiable in the channels (reverse mode).

    Args:
        h_re, h_im: Dr.Jit ``Float`` [B*16], real and imaginary part of the channels
            (view-major, ``b*16 + m``; unitless).
        frequency_hz: carrier, Hz; ``height, width``: grid [pixels].
        normalize: min-max normalise each image.
    Returns:
        ``Float`` [B*height*width] (the images view-major).
    """
    import drjit as dr

    if not dr.grad_enabled(h_re, h_im):
        img = Images(_channels(h_re, h_im), frequency_hz=frequency_hz, height=height, width=width,
                     normalize=normalize, threads=min(THREADS, dr.thread_count()), keep=False)
        return B.Float(img.out.reshape(-1))
    return dr.custom(_op_class(), h_re, h_im, float(frequency_hz), int(height), int(width), bool(normalize))
