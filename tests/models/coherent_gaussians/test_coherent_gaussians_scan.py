"""rfmitsuba.models.coherent_gaussians.scan: the directional scan of the training PAS.

The scan finds the wall that made the data; every pixel's look direction reads back that pixel on
the full grid and on coarse ones; the greedy pursuit picks as scoring every direction anew at every
pick."""
from __future__ import annotations

import numpy as np
import pytest
from coherent_gaussians_cases import F


#: every test on one Dr.Jit thread (the ``one_thread`` fixture of tests/conftest.py)
pytestmark = pytest.mark.usefixtures("one_thread")


def test_scan_finds_the_wall_that_made_the_data():
    """PAS drawn by a field with the direct path and the image across x = 0.6: the data scan of
    an unknown room (direct path explained first, then matching pursuit on arrival directions)
    finds a plane across x among its first two, within 0.4 m of x = 0.6 (seen from 2-3 m, a plane's
    offset moves its image's direction by a few degrees per 10 cm, less than the array's beam: the
    scan places planes coarsely and training refines them)."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.base import Views, render
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField, scan

    rng = np.random.default_rng(0)
    n = 40
    q = np.array([1.5, 0.5, 0.8]) + rng.random((n, 3)) * [1.5, 2.0, 1.0]
    x = np.tile([3.8, 3.0, 2.2], (n, 1))
    A = np.stack([np.eye(3), np.diag([-1.0, 1.0, 1.0])])
    f = CoherentGaussianField(A, np.array([0, 1]), np.zeros((0, 3)), cfg=CoherentGaussianConfig(), readout="amplitude",
                              wavefront="plane", vis_center=np.array([2.0, 1.5, 1.3]), frequency_hz=F)
    f.params["img_offset"] = B.Float(np.array([0, 0, 0, 1.2, 0, 0], np.float32))
    f.params["img_amp"] = B.Float(np.array([1, 0, 0.8, 0], np.float32))
    views = Views(antenna_pos=q, view_pos=x, transmitter=q, rx_to_world=None, frequency_hz=F, task="tx")
    pas = render([f], views, height=45, width=180).numpy()
    got = scan(pas, x, q, images=2, scatterers=2, step=0.1, margin=2.0)
    found = [float(b[0]) / 2 for a, b in zip(got["A"], got["b"]) if a[0, 0] == -1]
    assert any(abs(v - 0.6) <= 0.4 for v in found), (got["A"], got["b"], got["image_score"])
    assert got["points"].shape == (2, 3)


@pytest.mark.parametrize("h", [90, 45, 18])
def test_pas_lookup_reads_the_pixel_of_its_own_direction(h):
    """Every pixel's look direction (rfmitsuba.rf.grid, block centres on a coarse grid) reads
    back that pixel, on the full grid and on coarse ones."""
    from rfmitsuba.models.coherent_gaussians import pas_lookup
    from rfmitsuba.rf.grid import directions

    d = 90 // h
    pas = np.arange(h * 4 * h, dtype=np.float64).reshape(1, h, 4 * h)
    u = directions(resolution_deg=d).reshape(1, -1, 3)
    np.testing.assert_array_equal(pas_lookup(pas, u), pas.reshape(1, -1))


def test_greedy_picks_as_scoring_every_direction_at_every_pick():
    """The scan's greedy pursuit turns candidate directions into pixels once; its picks match
    scoring every candidate's directions anew at every pick (the definition)."""
    from rfmitsuba.models.coherent_gaussians.scan import _greedy, _Residual, _unit

    rng = np.random.default_rng(7)
    pas = rng.random((12, 45, 180))
    dirs = _unit(rng.normal(size=(12, 300, 3)))
    allowed = rng.random(300) > 0.2
    want, res, ok = [], _Residual(pas, 12.0), allowed.copy()
    for _ in range(10):
        sc = np.where(ok, res.score(dirs), -np.inf)
        i = int(np.argmax(sc))
        want.append(i)
        ok[i] = False
        res.explain(dirs[:, i])
    assert _greedy(_Residual(pas, 12.0), dirs, 10, allowed=allowed) == want
