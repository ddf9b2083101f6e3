"""Differentiable Bartlett PAS of the 4x4 array in Dr.Jit: channels -> (normalised) PAS images.

The PAS is ``P(el, az) = | sum_m w_m(el, az) h_m |`` with the beamformer weights
``w_m = conj(v_m) / M`` of :func:`rfmitsuba.rf.bartlett_ref.beamformer` (the same sign convention, the
same grid: row ``i`` = elevation ``(i + 1)`` degrees, column ``j`` = azimuth ``j`` degrees).
:func:`pas` computes it for B channels at once and, with ``normalize=True``, min-max
normalises every image inside the same operation, as the metric and the training loss
see it.

The operation is a ``drjit.CustomOp`` with a hand-written adjoint, so the backward pass
needs no atomic scatter: the forward pass sums over the 16 elements (lanes ``[b, pixel, m]``,
``block_sum`` of 16) and the backward pass over the pixels (lanes ``[b, m, pixel]``,
``block_sum`` of H*W), with

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


def weights(*, frequency_hz: float, height: int = 90, width: int = 360):
    """Beamformer weights of a ``height x width`` grid as two Dr.Jit ``Float`` [H*W*16]
    (real, imaginary; layout ``pixel*16 + m``). Cached per (frequency, grid, backend)."""

    if 90 % height or 360 % width or 360 // width != 90 // height:
        raise ConfigError(f"PAS grid must be 90/d x 360/d, got {height} x {width}")
    key = (float(frequency_hz), height, width, B.variant())
    if key not in _cache:
        w = _pas.beamformer(frequency_hz=frequency_hz, resolution_deg=90.0 / height)  # [H*W, 16]
        _cache[key] = (B.Float(np.ascontiguousarray(w.real.ravel(), np.float32)),
                       B.Float(np.ascontiguousarray(w.imag.ravel(), np.float32)))
    return _cache[key]


def _op_class():
    if "op" in _cache:
        return _cache["op"]
    import drjit as dr

    class BartlettPAS(dr.CustomOp):
        def eval(self, h_re, h_im, w_re, w_im, views, pixels, normalize):
            self.views, self.pixels, self.normalize = views, pixels, normalize
            self.w_re, self.w_im = w_re, w_im
            M = NUM_ELEMENTS
            lane = dr.arange(B.UInt32, views * pixels * M)
            m = lane % M
            bp = lane // M                      # b * pixels + pixel
            pix = bp % dr.opaque(B.UInt32, pixels)
            b = bp // dr.opaque(B.UInt32, pixels)
            hr = dr.gather(B.Float, h_re, b * M + m)
            hi = dr.gather(B.Float, h_im, b * M + m)
            wr = dr.gather(B.Float, w_re, pix * M + m)
            wi = dr.gather(B.Float, w_im, pix * M + m)
            yr = dr.block_sum(wr * hr - wi * hi, M)
            yi = dr.block_sum(wr * hi + wi * hr, M)
            p = dr.sqrt(yr * yr + yi * yi)
            dr.eval(yr, yi, p)
            self.yr, self.yi, self.p = yr, yi, p
            if not normalize:
                return p
            lo = dr.block_reduce(dr.ReduceOp.Min, p, pixels)
            hi_ = dr.block_reduce(dr.ReduceOp.Max, p, pixels)
            img = dr.arange(B.UInt32, views * pixels) // dr.opaque(B.UInt32, pixels)
            lo_b = dr.gather(B.Float, lo, img)
            hi_b = dr.gather(B.Float, hi_, img)
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
            img = dr.arange(B.UInt32, views * pixels) // dr.opaque(B.UInt32, pixels)
            if self.normalize:
                inv = 1.0 / self.span_b
                gp = g * inv
                # d/dlo: sum g (Pn - 1)/span;  d/dhi: -sum g Pn/span  (per image)
                dlo = dr.block_sum(g * (self.pn - 1.0) * inv, pixels)
                dhi = dr.block_sum(-g * self.pn * inv, pixels)
                is_lo = self.p == self.lo_b
                is_hi = (self.p == self.hi_b) & ~is_lo
                gp = gp + dr.select(is_lo, dr.gather(B.Float, dlo, img), 0.0) \
                    + dr.select(is_hi, dr.gather(B.Float, dhi, img), 0.0)
            else:
                gp = g
            scale = gp / dr.maximum(self.p, 1e-30)
            gyr, gyi = scale * self.yr, scale * self.yi
            dr.eval(gyr, gyi)
            # lanes [b, m, pixel]: dL/dh_m = sum_pixel gy * conj(w_m)
            lane = dr.arange(B.UInt32, views * M * pixels)
            pix = lane % dr.opaque(B.UInt32, pixels)
            bm = lane // dr.opaque(B.UInt32, pixels)
            m = bm % M
            b = bm // M
            ar = dr.gather(B.Float, gyr, b * pixels + pix)
            ai = dr.gather(B.Float, gyi, b * pixels + pix)
            wr = dr.gather(B.Float, self.w_re, pix * M + m)
            wi = dr.gather(B.Float, self.w_im, pix * M + m)
            # (ar + j ai) * (wr - j wi)
            self.set_grad_in("h_re", dr.block_sum(ar * wr + ai * wi, pixels))
            self.set_grad_in("h_im", dr.block_sum(ai * wr - ar * wi, pixels))

        def name(self):
            return "BartlettPAS"

    _cache["op"] = BartlettPAS
    return BartlettPAS


def bartlett(h_re, h_im, *, frequency_hz: float, height: int = 90, width: int = 360, normalize: bool = True):
    """PAS images of B channels, differentiable in the channels.

    Args:
        h_re, h_im: Dr.Jit ``Float`` [B*16] (or NumPy float32 [B, 16]), real and imaginary part
            of the narrowband channel at each element (view-major, ``b*16 + m``; unitless).
        frequency_hz: carrier, Hz.
        height, width: grid (90 x 360 is the project's; 90/d x 360/d samples it at d degrees).
        normalize: min-max normalise each image to [0, 1] (the training loss's and the metric's view).
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
    w_re, w_im = weights(frequency_hz=frequency_hz, height=height, width=width)
    out = dr.custom(_op_class(), h_re, h_im, w_re, w_im, views, height * width, bool(normalize))
    return B.TensorXf(out, shape=(views, height, width))
