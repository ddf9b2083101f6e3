"""Tests of rfmitsuba.splat.tiles: the device-built tile lists hold every
(tile, Gaussian) pair with a visible pixel, front to back, and agree with the
independent NumPy construction."""
from __future__ import annotations

import drjit as dr
import numpy as np
import pytest
from test_render import random_scene, to_jit

from rfmitsuba.core import backend as B
from rfmitsuba.splat import reference as ref
from rfmitsuba.splat import tiles
from rfmitsuba.splat.project import project


def projected(scene, rx, h, w):
    jit = to_jit(*scene)
    n = len(scene[4])
    views = len(rx)
    k = dr.arange(B.UInt32, views * n)
    view = k // n
    arrays = [dr.gather(type(a), a, k - view * n) for a in jit]
    rx_j = dr.gather(B.Array3f, B.Array3f(*(B.Float(np.float32(rx[:, i])) for i in range(3))), view)
    eye = [[B.Float(float(i == j)) for j in range(3)] for i in range(3)]
    return project(*arrays, rx_j, eye, height=h, width=w, near=0.05), n


def lists_of(lists, views, h, w):
    entries = lists.entries.numpy()[:lists.count]
    offsets = lists.offsets.numpy()
    nty, ntx = tiles.tile_grid(h, w)
    assert offsets.shape == (views * nty * ntx + 1,) and offsets[-1] <= len(entries)
    return [entries[offsets[t]:offsets[t + 1]] for t in range(len(offsets) - 1)]


@pytest.mark.parametrize("cull", [False, True])
def test_lists_cover_every_visible_pair_in_depth_order(variant, cull):
    # With the conic (``cull``), the pairs whose tile the ellipse misses leave the lists:
    # every pixel the reference draws must still find its Gaussian in its tile's list.
    rng = np.random.default_rng(0)
    scene = random_scene(rng, 60)
    rx = np.array([[0.1, 0.2, 0.0], [0.5, -0.3, 0.4]])
    h, w = 18, 72
    p, n = projected(scene, rx, h, w)
    fields = [dr.detach(getattr(p, f)) for f in ("u", "v", "cov_uu", "cov_vv", "opacity", "depth")]
    conic = tuple(dr.detach(x) for x in (p.conic_a, p.conic_b, p.conic_c)) if cull else None
    lists = tiles.build(*fields, views=2, n=n, height=h, width=w, conic=conic)
    got = lists_of(lists, 2, h, w)
    if cull:  # some corners of the boxes were dropped; the pair arrays keep them
        uncut = tiles.build(*fields, views=2, n=n, height=h, width=w)
        assert lists.count == uncut.count and lists.offsets.numpy()[-1] < 0.95 * uncut.count
    depth = p.depth.numpy()
    nty, ntx = tiles.tile_grid(h, w)
    jj, ii = np.meshgrid(np.arange(w), np.arange(h))
    for b in range(2):
        m, ls, rot, op, _ = (a for a in scene)
        u, v, cov, dist = ref.project_one(m, ls, rot, rx[b], np.eye(3), h, w)
        for i in range(n):
            if dist[i] < 0.05:
                continue
            conic = np.linalg.inv(cov[i])
            du = jj - u[i]
            du = np.where(du >= w / 2, du - w, np.where(du < -w / 2, du + w, du))
            dv = ii - v[i]
            alpha = op[i] * np.exp(-0.5 * (conic[0, 0] * du**2 + 2 * conic[0, 1] * du * dv + conic[1, 1] * dv**2))
            for r, c in zip(*np.nonzero(alpha >= tiles.ALPHA_MIN * (1 + 1e-4))):
                t = b * nty * ntx + (r // tiles.TILE_H) * ntx + c // tiles.TILE_W
                assert b * n + i in got[t], f"view {b} Gaussian {i} missing from tile {t}"
    for t, lst in enumerate(got):
        assert np.all(lst // n == t // (nty * ntx))  # only the tile's own view
        assert np.all(np.diff(depth[lst]) >= 0)  # front to back
        assert len(set(lst.tolist())) == len(lst)  # no duplicates (wrapped boxes merged)


def test_device_lists_equal_numpy_construction(variant):
    rng = np.random.default_rng(1)
    scene = random_scene(rng, 120)
    rx = np.array([[0.0, 0.0, 0.3]])
    for h, w in ((90, 360), (20, 44)):
        p, n = projected(scene, rx, h, w)
        fields = [dr.detach(getattr(p, f)) for f in ("u", "v", "cov_uu", "cov_vv", "opacity", "depth")]
        dev = lists_of(tiles.build(*fields, views=1, n=n, height=h, width=w), 1, h, w)
        host = tiles.build_numpy(*(f.numpy() for f in fields), views=1, height=h, width=w)
        for t, lst in enumerate(dev):
            expected = host.entries[host.offsets[t]:host.offsets[t + 1]]
            # The device boxes are widened by 1e-5 relative: they may hold a few more
            # Gaussians, never fewer, in the same order.
            assert set(expected.tolist()) <= set(lst.tolist())
            assert [e for e in lst if e in set(expected.tolist())] == expected.tolist()


def test_no_pairs(variant):
    zeros = B.Float(np.zeros(4, np.float32))
    lists = tiles.build(zeros, zeros, zeros + 1, zeros + 1, zeros, zeros + 1, views=1, n=4, height=16, width=16)
    assert lists.count == 0 and not np.any(lists.offsets.numpy())


def test_ellipse_tile_test_never_misses_a_pixel(variant):
    # _reaches (the least q over a rectangle) against a dense grid in float64: wherever some
    # point of the rectangle has q <= k2 it must answer True; and it drops most rectangles the
    # ellipse misses by a margin (else the test would cull nothing).
    rng = np.random.default_rng(11)
    k = 4000
    ang = rng.uniform(0, np.pi, k)
    s1, s2 = rng.uniform(0.3, 6.0, k), rng.uniform(0.3, 6.0, k)
    ca = np.cos(ang) ** 2 / s1**2 + np.sin(ang) ** 2 / s2**2
    cc = np.sin(ang) ** 2 / s1**2 + np.cos(ang) ** 2 / s2**2
    cb = np.sin(ang) * np.cos(ang) * (1 / s1**2 - 1 / s2**2)
    du0, dv0 = rng.uniform(-25, 20, k), rng.uniform(-25, 20, k)
    du1, dv1 = du0 + 7, dv0 + rng.choice([3.0, 7.0], k)
    k2 = 2 * np.log(rng.uniform(0.05, 1.0, k) * 255)
    f = lambda a: B.Float(np.float32(a))  # noqa: E731
    got = tiles._reaches(f(ca), f(cb), f(cc), f(du0), f(du1), f(dv0), f(dv1), f(k2)).numpy()
    t = np.linspace(0, 1, 57)
    x = du0[:, None, None] + (du1 - du0)[:, None, None] * t[None, :, None]
    y = dv0[:, None, None] + (dv1 - dv0)[:, None, None] * t[None, None, :]
    q = ca[:, None, None] * x * x + 2 * cb[:, None, None] * x * y + cc[:, None, None] * y * y
    qmin = q.reshape(k, -1).min(1)
    assert np.all(got[qmin <= k2])
    far = qmin > 1.01 * k2 + 0.1
    assert far.sum() > k // 4 and not np.any(got & (qmin > 1.5 * k2 + 1))
    # not positive definite, or NaN: kept
    assert tiles._reaches(f([1.0, np.nan]), f([2.0, 0.0]), f([1.0, 1.0]), f([50.0, 50.0]), f([57.0, 57.0]),
                          f([50.0, 50.0]), f([57.0, 57.0]), f([1.0, 1.0])).numpy().tolist() == [True, True]
