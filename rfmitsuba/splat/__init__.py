"""Differentiable azimuth-elevation Gaussian splatting.

:func:`render` draws power angular spectra (PAS layout, docs/conventions.md, rows = elevation
(i+1)*90/H degrees, columns = azimuth j*360/W degrees, array frame) of N 3D
Gaussians seen from B receiver positions, differentiable in reverse mode.

Pipeline (one call):

1. :mod:`.project` -- every (view, Gaussian) pair becomes a 2D Gaussian in
   pixel units via the Jacobian of the direction map (Dr.Jit, AD).
2. :mod:`.tiles` -- tile lists (8x8-pixel tiles), front to back by distance
   from the receiver, built on the device (one synchronisation: the number
   of pairs).
3. :mod:`.raster` -- compositing loop over each tile's list (8 lanes per
   tile, 8 pixels per lane, on the LLVM backend) with a hand-written backward
   (``dr.CustomOp``).

Per-Gaussian arrays are repeated for the B views by :mod:`.per_view`, whose
gradient sums the views with gathers instead of atomic additions.

No kernel depends on N, on the number of pairs or on the batch size B (for
B >= 2), so densification does not recompile anything. ``render(...,
check=True)`` (the default, and the trainer's) validates the parameter values
with one fused reduction per array size and a synchronisation, and names the
problem; with ``check=False`` (the benchmarks) non-finite or degenerate
geometry drops those Gaussians (never a crash), non-finite signals give
non-finite pixels.

Definitions: ``I = sum_i T_i alpha_i s_i``, ``T_i = prod_{j<i}(1 - alpha_j)``,
``alpha_i = min(0.99, opacity_i exp(-d^T Sigma^-1 d / 2))``, contributions with
``alpha < 1/255`` skipped; azimuth distance wraps (nearest of the 360-degree
copies); below-horizon Gaussians are mirrored to ``|elevation|`` (a horizontal
array cannot tell up from down); Gaussians closer than ``near`` are culled;
``Sigma`` includes a 0.3 px^2 blur (as 3DGS).
"""
from .project import DILATION
from .render import as_jit_array, render
from .tiles import ALPHA_MAX, ALPHA_MIN, TILE_H, TILE_W

__all__ = ["render", "as_jit_array", "ALPHA_MAX", "ALPHA_MIN", "DILATION", "TILE_H", "TILE_W"]
