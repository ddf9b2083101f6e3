"""The same splatting math in vectorised PyTorch (CPU), for the benchmark only.

A global pixel-pair list: every (pixel, Gaussian) pair inside the Gaussian's
bounding box (the box of :mod:`.tiles`, per pixel instead of per tile),
sorted by pixel and then by distance. Alphas, a segmented exclusive scan of
``log(1 - alpha)`` in float64 for the transmittance, and ``index_add`` into
the image; PyTorch's autograd gives the backward. Same definitions as
:mod:`rfmitsuba.splat` (dilation, thresholds, nearest-copy azimuth wrap,
mirrored elevation, near culling), checked against it in the tests.

Needs the optional extra ``torch`` (``pip install rfmitsuba[torch]``).
"""
from __future__ import annotations

import math

import numpy as np

from .project import DILATION, ZENITH_EPS
from .tiles import ALPHA_MAX, ALPHA_MIN


def project(torch, means, log_scales, rotations, opacities, rx, *, height, width, near):
    """Torch twin of :func:`rfmitsuba.splat.project.project` for one view (identity frame).

    Returns u, v, (conic a, b, c), cov_uu, cov_vv, opacity (0 if culled), depth; tensors [N].
    """
    d = means - rx
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    rho2 = x * x + y * y
    r2 = rho2 + z * z
    rho2c = torch.maximum(rho2, (ZENITH_EPS * ZENITH_EPS) * r2)
    rho = torch.sqrt(rho2c)
    su = width / (2 * math.pi)
    sv = 2 * height / math.pi
    az = torch.atan2(y, x)
    az = torch.where(az < 0, az + 2 * math.pi, az)
    u = az * su
    u = torch.where(u >= width, u - width, u)
    v = torch.atan2(z.abs(), rho) * sv - 1.0
    zero = torch.zeros_like(x)
    ju = torch.stack([-y / rho2c * su, x / rho2c * su, zero], 1)
    k = -z.abs() / (r2 * rho) * sv
    jv = torch.stack([k * x, k * y, torch.sign(z) * rho / r2 * sv], 1)
    q = rotations / rotations.norm(dim=1, keepdim=True)
    w, qx, qy, qz = q.unbind(1)
    Rg = torch.stack([
        torch.stack([1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - w * qz), 2 * (qx * qz + w * qy)], 1),
        torch.stack([2 * (qx * qy + w * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - w * qx)], 1),
        torch.stack([2 * (qx * qz - w * qy), 2 * (qy * qz + w * qx), 1 - 2 * (qx * qx + qy * qy)], 1),
    ], 1)
    M = Rg * torch.exp(log_scales)[:, None, :]
    tu = torch.einsum("ni,nic->nc", ju, M)
    tv = torch.einsum("ni,nic->nc", jv, M)
    cuu = (tu * tu).sum(1) + DILATION
    cvv = (tv * tv).sum(1) + DILATION
    cuv = (tu * tv).sum(1)
    det = cuu * cvv - cuv * cuv
    r = torch.sqrt(r2)
    op = torch.where(r >= near, opacities, torch.zeros_like(opacities))
    return u, v, (cvv / det, -cuv / det, cuu / det), cuu, cvv, op, r


def pixel_pairs(u, v, cuu, cvv, op, depth, *, height, width):
    """numpy float32 [N] each -> (gaussian int64 [P], pixel int64 [P], segment starts bool [P]),
    pairs sorted by pixel, then front to back."""
    ok = np.isfinite(u) & np.isfinite(v) & (op >= ALPHA_MIN)
    k2 = 2.0 * np.log(np.where(ok, op, 1.0) / ALPHA_MIN)
    eu = np.sqrt(k2 * cuu)
    ev = np.sqrt(k2 * cvv)
    r0 = np.maximum(np.ceil(v - ev), 0).astype(np.int64)
    r1 = np.minimum(np.floor(v + ev), height - 1).astype(np.int64)
    c0 = np.ceil(u - eu)
    c1 = np.floor(u + eu)
    full = (c1 - c0 + 1) >= width
    c0 = np.where(full, 0, c0).astype(np.int64)
    c1 = np.where(full, width - 1, c1).astype(np.int64)
    ok &= (r0 <= r1) & (c0 <= c1)
    idx = np.flatnonzero(ok)
    idx = idx[np.argsort(depth[idx], kind="stable")]
    nc = (c1 - c0 + 1)[idx]
    count = (r1 - r0 + 1)[idx] * nc
    start = np.cumsum(count) - count
    rep = np.repeat(np.arange(idx.size), count)
    k = np.arange(int(count.sum())) - start[rep]
    row = r0[idx][rep] + k // nc[rep]
    col = np.mod(c0[idx][rep] + k % nc[rep], width)
    pixel = row * width + col
    order = np.argsort(pixel.astype(np.uint16) if height * width <= 65536 else pixel, kind="stable")
    pixel = pixel[order]
    gauss = idx[rep[order]]
    first = np.ones(pixel.size, bool)
    first[1:] = pixel[1:] != pixel[:-1]
    return gauss, pixel, first


def render(torch, means, log_scales, rotations, opacities, signals, rx, *, height=90, width=360, near=0.05):
    """One PAS image [height, width] (torch tensor, autograd) from torch tensors [N, k] / [N]."""
    u, v, (ca, cb, cc), cuu, cvv, op, depth = project(
        torch, means, log_scales, rotations, opacities, rx, height=height, width=width, near=near)
    host = [t.detach().numpy() for t in (u, v, cuu, cvv, op, depth)]
    g, pix, first = pixel_pairs(*host, height=height, width=width)
    g_t = torch.from_numpy(g)
    pix_t = torch.from_numpy(pix)
    px = (pix_t % width).to(u.dtype)
    py = (pix_t // width).to(u.dtype)
    du = px - u[g_t]
    du = torch.where(du >= width / 2, du - width, du)
    du = torch.where(du < -width / 2, du + width, du)
    dv = py - v[g_t]
    q = ca[g_t] * du * du + 2 * cb[g_t] * du * dv + cc[g_t] * dv * dv
    alpha = torch.clamp(op[g_t] * torch.exp(-0.5 * q), max=ALPHA_MAX)
    alpha = torch.where(alpha >= ALPHA_MIN, alpha, torch.zeros_like(alpha))
    # Exclusive segmented scan of log(1 - alpha), in float64 (a float32 global scan loses precision).
    la = torch.log1p(-alpha.double())
    incl = torch.cumsum(la, 0)
    seg = torch.from_numpy(np.cumsum(first) - 1)
    seg_start = torch.from_numpy(np.flatnonzero(first))
    base = (incl - la)[seg_start][seg]
    T = torch.exp(incl - la - base).to(alpha.dtype)
    image = torch.zeros(height * width, dtype=u.dtype).index_add(0, pix_t, T * alpha * signals[g_t])
    return image.view(height, width)
