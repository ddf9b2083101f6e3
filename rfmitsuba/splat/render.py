"""Public entry point: render PAS images from 3D Gaussians (see :func:`render`)."""
from __future__ import annotations

import math

import drjit as dr
import numpy as np

from ..core import backend as B
from ..core.errors import GaussianError
from ..core.upload import upload, upload_columns
from .per_view import per_view
from .project import project
from .raster import rasterize

#: log-scale window inside which exp(log_scale) is a finite, positive float32.
LOG_SCALE_RANGE = (-87.0, 88.0)


def as_jit_array(x, kind: str, name: str = "array"):
    """numpy [N, k] / [N] or a Dr.Jit array -> Dr.Jit array of the backend.

    ``kind`` is ``"Array3f"``, ``"Array4f"`` or ``"Float"``. NumPy input is
    converted one component at a time: ``Array3f(numpy [3, N])`` would gather
    lazily from one flat array with N compiled into the kernel, so every new N
    (densification) would recompile. Raises GaussianError on a wrong shape.
    """
    dims = {"Array3f": 3, "Array4f": 4, "Float": 1}[kind]
    tp = getattr(B, kind)
    if isinstance(x, tp):
        return x
    if dr.is_array_v(x):
        if dims == 1 and dr.depth_v(x) == 1:
            return B.Float(x)
        if dims > 1 and dr.depth_v(x) == 2 and len(x) == dims:
            return tp(x)
        raise GaussianError(f"{name}: expected a {kind} (or numpy [N{', %d' % dims if dims > 1 else ''}]), got {type(x).__name__}")
    a = np.asarray(x, dtype=np.float32)
    if dims == 1:
        if a.ndim != 1:
            raise GaussianError(f"{name}: expected shape [N], got {a.shape}")
        return upload(B.Float, a)
    if a.ndim != 2 or a.shape[1] != dims:
        raise GaussianError(f"{name}: expected shape [N, {dims}], got {a.shape}")
    # Component by component: Array3f(numpy [3, N]) would gather lazily from one
    # flat array with N baked into the kernel (a recompilation whenever N changes).
    return tp(*upload_columns(B.Float, a))


def _rx_array(rx_positions):
    """Receiver positions -> (Array3f [B], numpy float64 [B, 3])."""
    if dr.is_array_v(rx_positions):
        arr = B.Array3f(rx_positions)
        host = np.asarray(arr.numpy(), dtype=np.float64).reshape(3, -1).T
        return arr, host
    host = np.asarray(rx_positions, dtype=np.float64)
    if host.ndim == 1 and host.shape[0] == 3:
        host = host[None]
    if host.ndim != 2 or host.shape[1] != 3 or host.shape[0] == 0:
        raise GaussianError(f"rx_positions: expected shape [B, 3] with B >= 1, got {host.shape}")
    return B.Array3f(*upload_columns(B.Float, host.astype(np.float32))), host


def _value_tests(means, log_scales, rotations, opacities, signals) -> dict:
    """What :func:`_check_values` tests: the problem named -> Bool, true where it occurs (size N
    for the geometry, B*N for opacities and signals)."""
    lo, hi = LOG_SCALE_RANGE
    norm2 = dr.squared_norm(dr.detach(rotations))
    return {
        "means: non-finite value": ~dr.all(dr.isfinite(dr.detach(means))),
        "log_scales: non-finite value, or exp(log_scale) not a finite positive float32 "
        f"(log-scale outside [{lo}, {hi}])":
            ~dr.all(dr.detach(log_scales) > lo) | ~dr.all(dr.detach(log_scales) < hi),
        "rotations: non-finite value": ~dr.all(dr.isfinite(dr.detach(rotations))),
        "rotations: zero quaternion (cannot be normalised)": ~(norm2 > 1e-20),
        "opacities: non-finite value or outside [0, 1]":
            ~((dr.detach(opacities) >= 0) & (dr.detach(opacities) <= 1)),
        "signals: non-finite value": ~dr.isfinite(dr.detach(signals)),
    }


def _check_values(means, log_scales, rotations, opacities, signals) -> None:
    """Raises GaussianError naming the first problem and how many Gaussians have it. One fused
    test per array size (two reductions, evaluated together); the per-problem counts are taken
    only when one of them fails (a training step ran 14 kernels for the six counts before)."""
    tests = _value_tests(means, log_scales, rotations, opacities, signals)
    by_size: dict = {}
    for bad in tests.values():
        w = dr.width(bad)
        by_size[w] = bad if w not in by_size else (by_size[w] | bad)
    flags = [dr.any(bad) for w, bad in by_size.items() if w]
    dr.eval(*flags)
    if not any(bool(f[0]) for f in flags):
        return
    counts = [dr.count(m) for m in tests.values()]
    dr.eval(*counts)
    for what, c in zip(tests, counts):
        if int(c[0] if dr.width(c) else 0) > 0:
            raise GaussianError(f"{what} in {int(c[0])} Gaussian(s)")


def render(means, log_scales, rotations, opacities, signals, rx_positions, *,
           rx_to_world=None, height: int = 90, width: int = 360, near: float = 0.05,
           check: bool = True, num_gaussians: int | None = None):
    """Render power angular spectra of Gaussians seen from one or more receivers.

    Args:
        means: Array3f [N or B*N] (or numpy [.., 3]), metres, world frame.
        log_scales: Array3f [N or B*N], natural log of the standard deviations, metres.
        rotations: Array4f [N or B*N], quaternion (w, x, y, z); normalised here.
        opacities: Float [N or B*N], attenuation delta in [0, 1].
        signals: Float [N or B*N], the signal each Gaussian emits (any unit).
        rx_positions: float [B, 3] (numpy or Array3f of size B), metres, world frame.
        rx_to_world: 3x3 rotation from the array frame to the world (default
            identity: array x, y horizontal, z up).
        height, width: image size, pixels; row i is elevation (i+1)*90/height
            degrees, column j is azimuth j*360/width degrees (PAS layout, docs/conventions.md).
        near: Gaussians closer than this to the receiver are culled, metres.
        check: validate values (one fused reduction and a synchronisation);
            the trainer may pass ``False``. Sizes are always checked.
        num_gaussians: N, the number of Gaussians per view. Needed when every array is per
            view (size B*N; otherwise N is taken as the smallest array size).

    Per-Gaussian arrays of size N are shared by every view; of size B*N
    they are per view, index b*N + i.

    Returns:
        TensorXf [B, height, width], differentiable (reverse mode) with
        respect to every Gaussian array. An empty Gaussian set gives zeros.

    Compositing front to back by distance from the receiver:
    ``I = sum_i T_i alpha_i s_i``, ``T_i = prod_{j<i} (1 - alpha_j)``,
    ``alpha_i = min(0.99, opacity_i exp(-d^T Sigma_i^-1 d / 2))``, terms with
    alpha < 1/255 skipped (as in 3DGS). See :mod:`rfmitsuba.splat`.

    Raises:
        GaussianError: mismatched sizes, bad image size; with ``check``:
            non-finite values, log-scales whose exp is not a finite positive
            float32, opacities outside [0, 1], zero quaternions.
    """
    B.ensure()
    if not (isinstance(height, (int, np.integer)) and isinstance(width, (int, np.integer))
            and height > 0 and width > 0):
        raise GaussianError(f"height and width must be positive integers, got {height!r} x {width!r}")
    height, width = int(height), int(width)
    if not (math.isfinite(near) and near >= 0):
        raise GaussianError(f"near must be a finite distance >= 0, got {near!r}")
    rx, rx_host = _rx_array(rx_positions)
    if not np.all(np.isfinite(rx_host)):
        raise GaussianError("rx_positions: non-finite value")
    views = rx_host.shape[0]
    R = np.eye(3) if rx_to_world is None else np.asarray(rx_to_world, dtype=np.float64)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)) or not np.allclose(R.T @ R, np.eye(3), atol=1e-4):
        raise GaussianError(f"rx_to_world must be a finite 3x3 rotation matrix, got {R.tolist()!r}")

    arrays = {
        "means": as_jit_array(means, "Array3f", "means"),
        "log_scales": as_jit_array(log_scales, "Array3f", "log_scales"),
        "rotations": as_jit_array(rotations, "Array4f", "rotations"),
        "opacities": as_jit_array(opacities, "Float", "opacities"),
        "signals": as_jit_array(signals, "Float", "signals"),
    }
    sizes = {k: dr.width(v) for k, v in arrays.items()}
    n = min(sizes.values()) if num_gaussians is None else int(num_gaussians)
    if any(s not in (n, views * n) for s in sizes.values()):
        raise GaussianError(
            f"per-Gaussian arrays must all have size N or B*N (B = {views} views); got sizes {sizes}")
    if n == 0:
        return B.TensorXf(dr.zeros(B.Float, views * height * width), (views, height, width))
    if check:
        _check_values(*arrays.values())

    m = views * n
    if views > 1:
        view = dr.arange(B.UInt32, m) // dr.opaque(B.UInt32, n)
        keys = [key for key in arrays if sizes[key] == n]
        arrays.update(zip(keys, per_view([arrays[key] for key in keys], views=views, n=n)))
        rx_per = dr.gather(B.Array3f, rx, view, mode=dr.ReduceMode.Direct)
    else:
        rx_per = rx
    Rm = [[dr.opaque(B.Float, float(R[i, j])) for j in range(3)] for i in range(3)]
    proj = project(arrays["means"], arrays["log_scales"], arrays["rotations"], arrays["opacities"],
                   arrays["signals"], rx_per, Rm, height=height, width=width, near=float(near))
    image = rasterize(proj, views=views, height=height, width=width)
    return B.TensorXf(image, (views, height, width))
