"""Plain dense reference twin of the splatting kernels (:mod:`rfmitsuba.splat.project` and
:mod:`rfmitsuba.splat.raster` through :func:`rfmitsuba.splat.render`), for parity tests.

Every pixel x every Gaussian, float64 NumPy, written from the definitions in the
rfmitsuba.splat docstrings without tiles, lists or bounding boxes. Its constants are written
again here on purpose (an independent twin); tests/splat/test_render.py checks that they
equal the kernels'. :func:`project_one` is the projection stage for one view, :func:`render` the
whole image. The PyTorch baseline of the benchmark (:mod:`rfmitsuba.splat.torch_baseline`) is
checked against it in tests/experiments/test_bench.py.
"""
from __future__ import annotations

import numpy as np

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
DILATION = 0.3
ZENITH_EPS = 1e-5


def quat_to_matrix(q):
    """q: [N, 4] (w, x, y, z), any norm -> [N, 3, 3]."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def project_one(means, log_scales, rotations, rx, R, height, width):
    """One view: returns u, v, cov [N,2,2], depth, all float64."""
    d = (means - rx) @ R  # R^T (m - rx) for each row
    x, y, z = d.T
    rho2 = x * x + y * y
    r2 = rho2 + z * z
    rho2c = np.maximum(rho2, ZENITH_EPS ** 2 * r2)
    rho = np.sqrt(rho2c)
    su = width / (2 * np.pi)
    sv = 2 * height / np.pi
    az = np.mod(np.arctan2(y, x), 2 * np.pi)
    u = az * su
    u = np.where(u >= width, u - width, u)
    v = np.arctan2(np.abs(z), rho) * sv - 1.0
    J = np.zeros((len(x), 2, 3))
    J[:, 0, 0] = -y / rho2c * su
    J[:, 0, 1] = x / rho2c * su
    J[:, 1, 0] = -np.abs(z) * x / (rho * r2) * sv
    J[:, 1, 1] = -np.abs(z) * y / (rho * r2) * sv
    J[:, 1, 2] = np.sign(z) * rho / r2 * sv
    Rg = quat_to_matrix(rotations)
    S = np.exp(log_scales)
    M = Rg * S[:, None, :]  # world axes as columns
    Ml = R.T[None] @ M
    cov3 = Ml @ np.transpose(Ml, (0, 2, 1))
    cov = J @ cov3 @ np.transpose(J, (0, 2, 1)) + DILATION * np.eye(2)
    return u, v, cov, np.sqrt(r2)


def render(means, log_scales, rotations, opacities, signals, rx_positions, *,
           rx_to_world=None, height=90, width=360, near=0.05, ambiguous=False):
    """Same arguments as rfmitsuba.splat.render but numpy float64 [N, k] / [B*N, k].

    With ``ambiguous=True`` also returns a bool [B, H, W] mask of pixels where some
    alpha lies within 1e-4 (relative) of the skip threshold, where float32
    rounding may legitimately keep or skip a contribution.
    """
    rx_positions = np.atleast_2d(np.asarray(rx_positions, np.float64))
    views = rx_positions.shape[0]
    R = np.eye(3) if rx_to_world is None else np.asarray(rx_to_world, np.float64)
    params = [np.asarray(a, np.float64) for a in (means, log_scales, rotations, opacities, signals)]
    n = min(len(a) for a in params)
    out = np.zeros((views, height, width))
    amb = np.zeros((views, height, width), bool)
    if n == 0:
        return (out, amb) if ambiguous else out
    jj, ii = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    for b in range(views):
        m, ls, rot, op, sig = (a[b * n:(b + 1) * n] if len(a) == views * n and views > 1 else a
                               for a in params)
        u, v, cov, depth = project_one(m, ls, rot, rx_positions[b], R, height, width)
        T = np.ones((height, width))
        img = np.zeros((height, width))
        for k in np.argsort(depth, kind="stable"):
            if depth[k] < near:
                continue
            conic = np.linalg.inv(cov[k])
            du = jj - u[k]
            du = np.where(du >= width / 2, du - width, du)
            du = np.where(du < -width / 2, du + width, du)
            dv = ii - v[k]
            q = conic[0, 0] * du * du + 2 * conic[0, 1] * du * dv + conic[1, 1] * dv * dv
            alpha = np.minimum(op[k] * np.exp(-0.5 * q), ALPHA_MAX)
            use = alpha >= ALPHA_MIN
            amb[b] |= np.abs(alpha / ALPHA_MIN - 1) < 1e-4
            img += np.where(use, T * alpha * sig[k], 0.0)
            T = np.where(use, T * (1 - alpha), T)
        out[b] = img
    return (out, amb) if ambiguous else out
