"""Bartlett read-out: from a splatted arrival spectrum to the PAS the 4x4 array measures.

The PAS is the Bartlett beamformer output of the array. A single plane wave from
direction q gives the pattern ``|AF(p, q)| = |sum_m exp(j k (x_m (u_q - u_p) + y_m (v_q - v_p)))| / M``
over look directions p, with direction cosines ``u = cos(el) cos(az)``, ``v = cos(el) sin(az)``
(array frame): a main lobe about 26 degrees wide with side lobes and the curved null arcs
seen in every PAS. A Gaussian splat is a smooth blob and cannot draw those arcs.

:class:`BartlettReadout` therefore treats the splatted image ``S`` (rendered at a coarser
"arrival" grid) as the angular density of arriving amplitude and returns
``PAS(p) = sum_q K[p, q] S(q)`` with ``K = |AF(p, q)|`` - the incoherent Bartlett response
of the array to the arrivals (exact for one path, an approximation where paths interfere).
It is linear, so gradients pass straight back to the Gaussians; the product with the fixed
kernel runs in NumPy (BLAS) inside a ``drjit.CustomOp``.
"""
from __future__ import annotations

import numpy as np

from ..core import backend as B
from .grid import angle_grid


def grid_directions(height: int, width: int, *, block: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre elevation and azimuth (radians) of a PAS grid, each float64 [height*width].

    ``block=None``: the splat renderer's grid (row i -> (i+1)*90/height deg, column j ->
    j*360/width deg). ``block=d``: the centres of d x d block means of the 90 x 360 PAS grid
    (row i -> i*d + (d+1)/2 deg, column j -> j*d + (d-1)/2 deg), as the training targets:
    :func:`rfmitsuba.rf.grid.angle_grid` at ``d`` degrees.
    """
    if block is not None:
        if (height, width) != (90 // block, 360 // block):
            raise ValueError(f"grid_directions: a {height}x{width} grid is not the {block}-degree block grid")
        el, az = angle_grid(resolution_deg=block)
        return el.ravel(), az.ravel()
    i, j = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    return np.deg2rad(((i + 1) * 90.0 / height).ravel()), np.deg2rad((j * 360.0 / width).ravel())


def bartlett_kernel(el_out, az_out, el_in, az_in, *, elements_wl: np.ndarray | None = None) -> np.ndarray:
    """``K[p, q] = |AF(p, q)|``: Bartlett response at look direction p to a unit plane wave from q.

    Args:
        el_out, az_out: float [P] look directions (radians, array frame).
        el_in, az_in: float [Q] arrival directions (radians).
        elements_wl: float [M, 2] element (x, y) positions in wavelengths; default the
            4x4 array at half-wavelength pitch (x fastest).

    Returns:
        float32 [P, Q] in [0, 1] (1 where p == q).
    """
    if elements_wl is None:
        c, r = np.meshgrid(np.arange(4) - 1.5, np.arange(4) - 1.5, indexing="xy")
        elements_wl = 0.5 * np.stack([c.ravel(), r.ravel()], 1)
    e = np.asarray(elements_wl, np.float64)
    uo, vo = np.cos(el_out) * np.cos(az_out), np.cos(el_out) * np.sin(az_out)
    ui, vi = np.cos(el_in) * np.cos(az_in), np.cos(el_in) * np.sin(az_in)
    # phase per element, look (P, M) and arrival (Q, M): 2 pi (x u + y v)
    po = 2 * np.pi * (np.outer(uo, e[:, 0]) + np.outer(vo, e[:, 1]))
    pi = 2 * np.pi * (np.outer(ui, e[:, 0]) + np.outer(vi, e[:, 1]))
    ao = np.exp(1j * po)
    ai = np.exp(1j * pi)
    return (np.abs(np.conj(ao) @ ai.T) / len(e)).astype(np.float32)


class BartlettReadout:
    """Linear map TensorXf [B, h_in, w_in] (arrival spectrum, splat grid) -> TensorXf
    [B, h_out, w_out] (Bartlett PAS on the grid of ``block`` x ``block`` means of 90 x 360).

    Args:
        h_in, w_in: arrival grid (the renderer's).
        h_out, w_out: output grid; ``block = 90 // h_out`` (must divide).
    """

    _cache: dict = {}

    def __init__(self, h_in: int, w_in: int, h_out: int, w_out: int):
        if 90 % h_out or 360 % w_out or 90 // h_out != 360 // w_out:
            raise ValueError(f"output grid {h_out}x{w_out} is not a block-mean grid of 90x360")
        self.shape_in, self.shape_out = (h_in, w_in), (h_out, w_out)
        key = (h_in, w_in, h_out, w_out)
        if key not in self._cache:
            eo, ao = grid_directions(h_out, w_out, block=90 // h_out)
            ei, ai = grid_directions(h_in, w_in)
            k = bartlett_kernel(eo, ao, ei, ai)
            # arrival pixels near the zenith cover a smaller solid angle: weight by cos(el)
            k *= np.cos(ei)[None, :].astype(np.float32)
            k /= k.sum(axis=1).mean()
            self._cache[key] = np.ascontiguousarray(k)
        self.kernel = self._cache[key]

    def __call__(self, img):
        """img: TensorXf [B, h_in, w_in] -> TensorXf [B, h_out, w_out], differentiable."""
        import drjit as dr

        b = img.shape[0]
        out = dr.custom(_readout_op(), img.array, self.kernel, b)
        return B.TensorXf(out, (b, *self.shape_out))


_OP = None


def _readout_op():
    global _OP
    if _OP is None:
        import drjit as dr

        class Readout(dr.CustomOp):
            def eval(self, x, kernel, b):
                self.kernel, self.b = kernel, b
                xs = np.asarray(x.numpy(), np.float32).reshape(b, -1)
                return B.Float((xs @ kernel.T).ravel())

            def forward(self):
                g = np.asarray(self.grad_in("x").numpy(), np.float32).reshape(self.b, -1)
                self.set_grad_out(B.Float((g @ self.kernel.T).ravel()))

            def backward(self):
                g = np.asarray(self.grad_out().numpy(), np.float32).reshape(self.b, -1)
                self.set_grad_in("x", B.Float((g @ self.kernel).ravel()))

            def name(self):
                return "BartlettReadout"

        _OP = Readout
    return _OP
