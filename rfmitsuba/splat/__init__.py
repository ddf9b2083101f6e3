"""Differentiable azimuth-elevation Gaussian splatting (issue 3).

:func:`render` draws power angular spectra (SPEC layout, rows = elevation
(i+1)*90/H degrees, columns = azimuth j*360/W degrees, array frame) of N 3D
Gaussians seen from B receiver positions, differentiable in reverse mode.

Pipeline (one call):

1. :mod:`.project` -- every (view, Gaussian) pair becomes a 2D Gaussian in
   pixel units via the Jacobian of the direction map (Dr.Jit, AD).
2. :mod:`.tiles` -- tile lists (2x8-pixel tiles), front to back by distance
   from the receiver (NumPy on the host, one synchronisation).
3. :mod:`.raster` -- per-pixel compositing loop with a hand-written backward
   (``dr.CustomOp``).

Definitions: ``I = sum_i T_i alpha_i s_i``, ``T_i = prod_{j<i}(1 - alpha_j)``,
``alpha_i = min(0.99, opacity_i exp(-d^T Sigma^-1 d / 2))``, contributions with
``alpha < 1/255`` skipped; azimuth distance wraps (nearest of the 360-degree
copies); below-horizon Gaussians are mirrored to ``|elevation|`` (a horizontal
array cannot tell up from down); Gaussians closer than ``near`` are culled;
``Sigma`` includes a 0.3 px^2 blur (as 3DGS).
"""
from .project import DILATION
from .render import render
from .tiles import ALPHA_MAX, ALPHA_MIN, TILE_H, TILE_W

__all__ = ["render", "ALPHA_MAX", "ALPHA_MIN", "DILATION", "TILE_H", "TILE_W"]
