"""Projection of 3D Gaussians onto the receiver's azimuth-elevation image.

Each (view, Gaussian) pair becomes a 2D Gaussian in *pixel units* of the PAS
image (PAS layout, docs/conventions.md): column coordinate ``u = azimuth * W / 360 deg`` in
``[0, W)`` and row coordinate ``v = elevation * H / 90 deg - 1`` (row ``i``
is elevation ``(i + 1) * 90 / H`` degrees, so for 90x360 row ``i`` is
``(i + 1)`` degrees and column ``j`` is ``j`` degrees).

Directions are taken in the array frame: ``d = rx_to_world^T (mean - rx)``.
Elevation is ``atan2(|d_z|, |d_xy|)``: a horizontal array cannot tell up from
down (docs/conventions.md), so a Gaussian below the array plane is drawn at the mirrored
elevation. Only its centre and covariance are mirrored (the Jacobian carries
``sign(d_z)``), the footprint is not duplicated across the horizon.

The 2D covariance is ``J Sigma_local J^T + DILATION * I`` with ``J`` the
Jacobian of the direction map ``(x, y, z) -> (u, v)`` at the Gaussian's mean
(pixels per metre) and ``Sigma_local = R^T Rg S^2 Rg^T R``. Near the zenith
``|d_xy|`` is clamped to ``1e-5 |d|``, so the azimuth extent becomes very wide
(the Gaussian covers all azimuths) but stays finite.

Everything here is plain Dr.Jit arithmetic, differentiated by Dr.Jit's AD.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr

from ..core import backend as B

#: Isotropic blur added to every projected covariance, pixels^2 (as in 3DGS):
#: keeps sub-pixel Gaussians visible and the conic well conditioned.
DILATION = 0.3
#: Smallest horizontal distance relative to the range, used at the zenith.
ZENITH_EPS = 1e-5


@dataclass
class Projected:
    """Per (view, Gaussian) 2D parameters, each a Float of size B*N (view-major).

    u, v: centre, pixels (u in [0, W)); conic_a/b/c: inverse covariance
    entries (a = S^-1_uu, b = S^-1_uv, c = S^-1_vv), 1/pixels^2;
    cov_uu, cov_vv: covariance diagonal, pixels^2; opacity: in [0, 1], 0 where
    culled (closer than ``near``); signal: as given; depth: distance from
    the receiver, metres.
    """

    u: object
    v: object
    conic_a: object
    conic_b: object
    conic_c: object
    cov_uu: object
    cov_vv: object
    opacity: object
    signal: object
    depth: object


def _quat_to_matrix(q):
    """Unit quaternion (w, x, y, z) -> 3x3 rotation as nested lists of Floats."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]


def project(means, log_scales, rotations, opacities, signals, rx, rx_to_world, *,
            height: int, width: int, near: float) -> Projected:
    """Project Gaussians into every view.

    Args:
        means: Array3f [M], metres, world frame (M = B*N, already expanded per view).
        log_scales: Array3f [M], natural log of metres.
        rotations: Array4f [M], quaternion (w, x, y, z), any non-zero norm.
        opacities: Float [M], in [0, 1].
        signals: Float [M].
        rx: Array3f [M], receiver position of the entry's view, metres.
        rx_to_world: 3x3 nested list of Float (size 1, opaque), array -> world.
        height, width: image size, pixels.
        near: Gaussians closer than this to the receiver are culled, metres.

    Returns:
        :class:`Projected`, every field of size M.
    """
    Float = B.Float
    R = rx_to_world
    dw = means - rx
    # Local direction d = R^T dw.
    d = [R[0][i] * dw[0] + R[1][i] * dw[1] + R[2][i] * dw[2] for i in range(3)]
    x, y, z = d
    rho2 = x * x + y * y
    r2 = rho2 + z * z
    rho2c = dr.maximum(rho2, (ZENITH_EPS * ZENITH_EPS) * r2)
    rho = dr.sqrt(rho2c)
    r = dr.sqrt(r2)

    su = width / (2.0 * math.pi)  # pixels per radian of azimuth
    sv = (2.0 * height) / math.pi  # pixels per radian of elevation
    az = dr.atan2(y, x)
    az = dr.select(az < 0, az + 2.0 * math.pi, az)
    u = az * su
    u = dr.select(u >= width, u - width, u)
    az_z = dr.abs(z)
    el = dr.atan2(az_z, rho)
    v = el * sv - 1.0

    # Jacobian rows (pixels per metre).
    inv_rho2 = dr.rcp(rho2c)
    ju = [-y * inv_rho2 * su, x * inv_rho2 * su, Float(0.0)]
    inv_r2 = dr.rcp(r2)
    k = -az_z * inv_r2 / rho * sv
    jv = [k * x, k * y, dr.sign(z) * rho * inv_r2 * sv]

    # M_local = R^T Rg diag(s): columns are the scaled principal axes.
    q = dr.normalize(rotations)
    Rg = _quat_to_matrix(q)
    s = [dr.exp(log_scales[i]) for i in range(3)]
    # World axes a_c = Rg[:, c] * s_c, local axes l_c = R^T a_c.
    tu = []
    tv = []
    for c in range(3):
        aw = [Rg[i][c] * s[c] for i in range(3)]
        al = [R[0][i] * aw[0] + R[1][i] * aw[1] + R[2][i] * aw[2] for i in range(3)]
        tu.append(ju[0] * al[0] + ju[1] * al[1])
        tv.append(jv[0] * al[0] + jv[1] * al[1] + jv[2] * al[2])
    cuu = tu[0] * tu[0] + tu[1] * tu[1] + tu[2] * tu[2] + DILATION
    cvv = tv[0] * tv[0] + tv[1] * tv[1] + tv[2] * tv[2] + DILATION
    cuv = tu[0] * tv[0] + tu[1] * tv[1] + tu[2] * tv[2]
    inv_det = dr.rcp(cuu * cvv - cuv * cuv)

    visible = r >= near
    return Projected(
        u=u, v=v,
        conic_a=cvv * inv_det, conic_b=-cuv * inv_det, conic_c=cuu * inv_det,
        cov_uu=cuu, cov_vv=cvv,
        opacity=dr.select(visible, opacities, 0.0),
        signal=signals, depth=r,
    )
