"""Differentiable Bartlett PAS of the 4x4 array in Dr.Jit: channels -> (normalised) PAS images.

The PAS is ``P(el, az) = | sum_m w_m(el, az) h_m |`` with the beamformer weights
``w_m = conj(v_m) / M`` of :func:`rfmitsuba.rf.bartlett_ref.beamformer` (the same sign convention, the
same grid: row ``i`` = elevation ``(i + 1)`` degrees, column ``j`` = azimuth ``j`` degrees).
:func:`pas` computes it for B channels at once and, with ``normalize=True``, min-max
normalises every image inside the same operation, as the metric and the training loss
see it.

The operation is a ``drjit.CustomOp`` with a hand-written adjoint, so neither pass needs an
atomic scatter or a materialised [B, pixels, 16] array:

* forward: lanes ``[pixel]``, the views unrolled. Each lane reads its 32 weights directly and
  each view's 16 channel values as scalars, so the 16-term sum is plain vector arithmetic
  (no gathers); the views' images are laid end to end.
* backward: lanes ``[chunk]`` (:func:`chunks` of them); lane ``c`` loops over pixels ``c, c + C,
  c + 2C, ...`` (neighbouring lanes read neighbouring pixels), reads each pixel's 32 weights once
  and accumulates the 16 complex sums of every view (up to ``UNROLL`` views per kernel); the
  chunks' partial sums are then laid end to end and added. On the CPU few chunks are best: the
  partial sums (2 x 16 x views per chunk) are written out, and with 4096 chunks writing them
  took as long as the loop (8 views, 45 x 180, one thread, load 3: the loop and the sums'
  kernels 2.53 + 1.99 ms with 4096 chunks, 2.07 + 0.12 ms with 128; ``docs/lab-notes/speed.md``);
  a GPU needs the lanes. The pixel count is compiled
  in as a literal, so index division is a multiplication, and the kernels compile once per grid
  and batch size (up to ``UNROLL``).

On the LLVM backend :func:`bartlett` runs the same op on the host by default
(:mod:`rfmitsuba.rf.bartlett_host`: its two matrix products on the host's BLAS, no tracing):
8 views at 90 x 360, forward 0.6 ms there against 2.5-8 ms here, where tracing the unrolled
views is most of the time. The kernels here run on CUDA and while a function is recorded
(``drjit.freeze``, where host code cannot run), and where ``host=False`` asks for them.

The gradient is

    dL/dh_m = sum_pixels  g_P * (y / |y|) * conj(w_m),      y = sum_m w_m h_m,

where ``g_P`` is the gradient at the raw PAS. With normalisation ``Pn = (P - lo)/(hi - lo)``
the gradient also flows through the image's minimum and maximum pixel (a subgradient where
several pixels tie). Reference: :func:`rfmitsuba.rf.bartlett_ref.bartlett` (NumPy, tests check parity
and finite differences).
"""
from __future__ import annotations

import numpy as np

from ..core import backend as B
from ..core.errors import ConfigError
from . import bartlett_ref as _pas
from .array import NUM_ELEMENTS

_cache: dict = {}


def weights(*, frequency_hz: float, height: int = 90, width: int = 360) -> tuple:
    """Beamformer weights of a ``height x width`` grid as 32 Dr.Jit ``Float`` [H*W] columns:
    the real parts of elements 0..15, then their imaginary parts. Cached per (frequency, grid,
    backend)."""

    if 90 % height or 360 % width or 360 // width != 90 // height:
        raise ConfigError(f"PAS grid must be 90/d x 360/d, got {height} x {width}")
    key = (float(frequency_hz), height, width, B.variant())
    if key not in _cache:
        w = _pas.beamformer(frequency_hz=frequency_hz, resolution_deg=90.0 / height)  # [H*W, 16]
        _cache[key] = tuple(B.Float(np.ascontiguousarray(part[:, m], np.float32))
                            for part in (w.real, w.imag) for m in range(NUM_ELEMENTS))
    return _cache[key]


#: lanes of the backward pass's reduction over pixels (each sums every C-th pixel), per backend
CHUNKS_CPU = 128
CHUNKS_GPU = 4096
#: views per kernel (both passes unroll their views)
UNROLL = 16


def chunks() -> int:
    """Lanes of the backward pass's reduction over pixels on the current backend."""
    return CHUNKS_GPU if B.is_cuda() else CHUNKS_CPU


def _op_class():
    if "op" in _cache:
        return _cache["op"]
    import drjit as dr

    class BartlettPAS(dr.CustomOp):
        def eval(self, h_re, h_im, w, views, pixels, normalize):
            self.views, self.pixels, self.normalize, self.w = views, pixels, normalize, w
            M = NUM_ELEMENTS
            # lanes [pixel], views unrolled (at most UNROLL per kernel, so kernels stay small and
            # few): the weights are read directly (no gather) once per pixel and each view's 16
            # channel values are scalars, so the 16-term sum is plain vector arithmetic; the
            # views' images are then laid end to end ([b, pixel])
            yrs, yis = [], []
            for b0 in range(0, views, UNROLL):
                # the group's channel values, each its own one-element array made in one small
                # kernel, which the pixel kernel reads once and broadcasts. Gathered there at a
                # literal index instead, a recorded step (dr.freeze) made every read a vector
                # gather (8 views, 45 x 180, one thread, load 3: the pixel kernel 2.8 ms, 0.44 ms
                # like this)
                hv = {(b, m, part): dr.gather(B.Float, h, B.UInt32(b * M + m))
                      for b in range(b0, min(views, b0 + UNROLL)) for m in range(M)
                      for part, h in (("re", h_re), ("im", h_im))}
                dr.eval(list(hv.values()))
                for b in range(b0, min(views, b0 + UNROLL)):
                    yr = yi = 0.0
                    for m in range(M):
                        hr, hi = hv[b, m, "re"], hv[b, m, "im"]
                        yr, yi = yr + (w[m] * hr - w[M + m] * hi), yi + (w[m] * hi + w[M + m] * hr)
                    yrs.append(yr)
                    yis.append(yi)
                dr.eval(yrs[b0:], yis[b0:])
            yr, yi = (dr.concat(yrs), dr.concat(yis)) if views > 1 else (yrs[0], yis[0])
            p = dr.sqrt(yr * yr + yi * yi)
            dr.eval(yr, yi, p)
            self.yr, self.yi, self.p = yr, yi, p
            if not normalize:
                return p
            lo = dr.block_reduce(dr.ReduceOp.Min, p, pixels)
            hi_ = dr.block_reduce(dr.ReduceOp.Max, p, pixels)
            b = dr.arange(B.UInt32, views * pixels) // pixels    # ``pixels`` a literal: no division
            lo_b = dr.gather(B.Float, lo, b)
            hi_b = dr.gather(B.Float, hi_, b)
            span_b = dr.maximum(hi_b - lo_b, 1e-30)
            pn = (p - lo_b) / span_b
            dr.eval(pn, lo_b, hi_b, span_b)
            self.lo_b, self.hi_b, self.span_b, self.pn = lo_b, hi_b, span_b, pn
            return pn

        def forward(self):
            raise NotImplementedError("BartlettPAS supports reverse-mode AD only")

        def backward(self):
            views, pixels, M = self.views, self.pixels, NUM_ELEMENTS
            g = self.grad_out()
            b = dr.arange(B.UInt32, views * pixels) // pixels
            if self.normalize:
                inv = 1.0 / self.span_b
                gp = g * inv
                # d/dlo: sum g (Pn - 1)/span;  d/dhi: -sum g Pn/span  (per image)
                dlo = dr.block_sum(g * (self.pn - 1.0) * inv, pixels)
                dhi = dr.block_sum(-g * self.pn * inv, pixels)
                is_lo = self.p == self.lo_b
                is_hi = (self.p == self.hi_b) & ~is_lo
                gp = gp + dr.select(is_lo, dr.gather(B.Float, dlo, b), 0.0) \
                    + dr.select(is_hi, dr.gather(B.Float, dhi, b), 0.0)
            else:
                gp = g
            scale = gp / dr.maximum(self.p, 1e-30)
            gyr, gyi = scale * self.yr, scale * self.yi
            dr.eval(gyr, gyi)
            # dL/dh_m = sum_pixel gy * conj(w_m): lanes [c] (C of them); lane c loops over
            # pixels c, c + C, c + 2C, ... (neighbouring lanes read neighbouring pixels), reads the
            # 32 weights once per pixel and accumulates the 16 complex sums of up to UNROLL views
            C = chunks()
            run = -(-pixels // C)
            c = dr.arange(B.UInt32, C)
            w, parts = self.w, []
            for b0 in range(0, views, UNROLL):
                group = range(b0, min(views, b0 + UNROLL))

                def body(j, *acc, group=group):
                    pix = j * C + c
                    ok = pix < pixels
                    wr = [dr.gather(B.Float, w[m], pix, ok) for m in range(M)]
                    wi = [dr.gather(B.Float, w[M + m], pix, ok) for m in range(M)]
                    out = []
                    for t, b in enumerate(group):
                        ar = dr.gather(B.Float, gyr, b * pixels + pix, ok)
                        ai = dr.gather(B.Float, gyi, b * pixels + pix, ok)
                        for m in range(M):
                            k = 2 * (t * M + m)
                            out += [acc[k] + (ar * wr[m] + ai * wi[m]), acc[k + 1] + (ai * wr[m] - ar * wi[m])]
                    return (j + 1, *out)

                state = dr.while_loop((B.UInt32(0), *(dr.zeros(B.Float, C) for _ in range(2 * M * len(group)))),
                                      lambda j, *acc: j < run, body)
                dr.eval(state[1:])                               # the loop: one kernel per group
                parts += state[1:]
            # the partial sums laid end to end ([b, m, re/im, c]), summed over the chunks
            sums = dr.block_sum(dr.concat(parts), C)         # [b*16 + m] * 2 + (0: re, 1: im)
            out = dr.arange(B.UInt32, views * M)
            g_re, g_im = dr.gather(B.Float, sums, 2 * out), dr.gather(B.Float, sums, 2 * out + 1)
            self.set_grad_in("h_re", g_re)
            self.set_grad_in("h_im", g_im)

        def name(self):
            return "BartlettPAS"

    _cache["op"] = BartlettPAS
    return BartlettPAS


def recording() -> bool:
    """Whether a function is being recorded (``drjit.freeze``) right now: values read back to the
    host there would be kept in the recording instead of each call's."""
    import drjit as dr

    flag = getattr(dr.JitFlag, "FreezingScope", None)
    return flag is not None and bool(dr.flag(flag))


def bartlett(h_re, h_im, *, frequency_hz: float, height: int = 90, width: int = 360, normalize: bool = True,
             host: bool | None = None):
    """PAS images of B channels, differentiable in the channels.

    Args:
        h_re, h_im: Dr.Jit ``Float`` [B*16] (or NumPy float32 [B, 16]), real and imaginary part
            of the narrowband channel at each element (view-major, ``b*16 + m``; unitless).
        frequency_hz: carrier, Hz.
        height, width: grid (90 x 360 is the project's; 90/d x 360/d samples it at d degrees).
        normalize: min-max normalise each image to [0, 1] (the training loss's and the metric's view).
        host: None (default): the op on the host (:mod:`rfmitsuba.rf.bartlett_host`: matrix
            products on the host's BLAS) on the LLVM backend, in this module's kernels on CUDA
            and while a function is recorded (``drjit.freeze``); True: on the host (an error
            while recording); False: in the kernels. Both give the same images and gradients to
            rounding, not to the bit.
    Returns:
        ``TensorXf`` [B, height, width].
    """
    import drjit as dr

    B.ensure()
    if isinstance(h_re, np.ndarray) or isinstance(h_im, np.ndarray):
        h_re = B.Float(np.ascontiguousarray(np.asarray(h_re, np.float32).ravel()))
        h_im = B.Float(np.ascontiguousarray(np.asarray(h_im, np.float32).ravel()))
    n = dr.width(h_re)
    if n % NUM_ELEMENTS or dr.width(h_im) != n:
        raise ConfigError(f"channels must be [B*16] real and imaginary parts, got sizes {n} and {dr.width(h_im)}")
    views = n // NUM_ELEMENTS
    w = weights(frequency_hz=frequency_hz, height=height, width=width)
    if host and recording():
        raise ConfigError("bartlett(host=True) cannot run while a function is recorded (drjit.freeze)")
    if host is None:
        host = not B.is_cuda() and not recording()
    if host and views:
        from . import bartlett_host

        out = bartlett_host.bartlett(h_re, h_im, frequency_hz=frequency_hz, height=height, width=width,
                                     normalize=normalize)
    else:
        out = dr.custom(_op_class(), h_re, h_im, w, views, height * width, bool(normalize))
    return B.TensorXf(out, shape=(views, height, width))
