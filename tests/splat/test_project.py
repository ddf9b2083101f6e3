"""Tests of rfmitsuba.splat.project: closed-form centres and covariances."""
from __future__ import annotations

import math

import numpy as np
import pytest
from test_render import to_jit

from rfmitsuba.core import backend as B
from rfmitsuba.splat.project import DILATION, project


def run(means, scales, rx=(0.0, 0.0, 0.0), rot=None, quats=None, h=90, w=360, near=0.05):
    n = len(means)
    quats = np.tile([1.0, 0, 0, 0], (n, 1)) if quats is None else np.asarray(quats, float)
    m, ls, q, op, sig = to_jit(np.asarray(means, float), np.log(np.asarray(scales, float)), quats,
                               np.full(n, 0.5), np.ones(n))
    R = np.eye(3) if rot is None else rot
    Rm = [[B.Float(float(R[i, j])) for j in range(3)] for i in range(3)]
    rx_j = B.Array3f(*(B.Float(float(c)) for c in rx))
    p = project(m, ls, q, op, sig, rx_j, Rm, height=h, width=w, near=near)
    return {k: getattr(p, k).numpy() for k in ("u", "v", "cov_uu", "cov_vv", "conic_b", "opacity", "depth")}


def test_on_the_horizon_along_x(variant):
    # 4 m along +x, isotropic 0.1 m: azimuth 0 -> u = 0, elevation 0 -> v = -1;
    # angular std 0.1/4 rad -> (0.025 * 180/pi)^2 px^2 on both axes (1 px = 1 deg).
    p = run([[4.0, 0, 0]], [[0.1, 0.1, 0.1]])
    sd = 0.025 * 180 / math.pi
    assert p["u"][0] == pytest.approx(0.0, abs=1e-4)
    assert p["v"][0] == pytest.approx(-1.0, abs=1e-4)
    assert p["cov_uu"][0] == pytest.approx(sd**2 + DILATION, rel=1e-4)
    assert p["cov_vv"][0] == pytest.approx(sd**2 + DILATION, rel=1e-4)
    assert p["conic_b"][0] == pytest.approx(0.0, abs=1e-7)
    assert p["depth"][0] == pytest.approx(4.0)


def test_direction_and_pixel_scale_for_other_resolutions(variant):
    # Azimuth 90 deg, elevation 45 deg: column W/4, row 45*H/90 - 1.
    for h, w in ((90, 360), (18, 72)):
        p = run([[0.0, 2.0, 2.0]], [[0.05] * 3], h=h, w=w)
        assert p["u"][0] == pytest.approx(w / 4, rel=1e-5)
        assert p["v"][0] == pytest.approx(45 * h / 90 - 1, rel=1e-5)


def test_radial_axis_does_not_widen_and_tangential_axes_do(variant):
    # Looking along +x at the horizon: the x scale is along the line of sight.
    radial = run([[3.0, 0, 0]], [[1.0, 0.05, 0.05]])
    vertical = run([[3.0, 0, 0]], [[0.05, 0.05, 0.6]])
    small = (0.05 / 3 * 180 / math.pi) ** 2 + DILATION
    assert radial["cov_uu"][0] == pytest.approx(small, rel=1e-4)
    assert radial["cov_vv"][0] == pytest.approx(small, rel=1e-4)
    assert vertical["cov_vv"][0] == pytest.approx((0.6 / 3 * 180 / math.pi) ** 2 + DILATION, rel=1e-4)


def test_below_the_array_plane_mirrors_elevation(variant):
    # The mirror image of a Gaussian in the array plane (mean z -> -z, rotation
    # (w, x, y, z) -> (w, -x, -y, z)) projects exactly like the Gaussian itself.
    w, x, y, z = 0.8, 0.3, -0.4, 0.33
    up = run([[1.0, 1.0, 1.5]], [[0.1, 0.2, 0.3]], quats=[[w, x, y, z]])
    down = run([[1.0, 1.0, -1.5]], [[0.1, 0.2, 0.3]], quats=[[w, -x, -y, z]])
    for k in ("u", "v", "cov_uu", "cov_vv", "conic_b", "depth"):
        assert down[k][0] == pytest.approx(up[k][0], rel=1e-4)
    assert abs(up["conic_b"][0]) > 1e-3  # a tilted footprint, so the check has teeth


def test_azimuth_range_and_zenith_finite(variant):
    p = run([[1.0, -1e-4, 0.2], [1e-7, 0.0, 3.0], [0.0, 0.0, 2.0]], [[0.1] * 3] * 3)
    assert 0 <= p["u"][0] < 360 and p["u"][0] > 359.9  # just below the seam
    assert np.all(np.isfinite(p["cov_uu"])) and np.all(p["v"][1:] == pytest.approx(89.0, abs=1e-3))


def test_near_culling_and_frame_rotation(variant):
    p = run([[0.03, 0, 0], [2.0, 0, 0]], [[0.1] * 3] * 2, near=0.05)
    assert p["opacity"].tolist() == [0.0, 0.5]
    # Array turned by 90 deg about z: a Gaussian at world +y is at array azimuth 0.
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # array x -> world y
    q = run([[0.0, 3.0, 0.5]], [[0.1, 0.1, 0.1]], rot=rot)
    assert q["u"][0] == pytest.approx(0.0, abs=1e-4) or q["u"][0] == pytest.approx(360.0, abs=1e-4)
