"""Tests of rfmitsuba.splat.raster on hand-made 2D Gaussians: closed-form
compositing, the alpha clamp and skip threshold, the wrap, and gradients."""
from __future__ import annotations

import math

import drjit as dr
import numpy as np
import pytest

from rfmitsuba.core import backend as B
from rfmitsuba.splat.project import Projected
from rfmitsuba.splat import raster, tiles
from rfmitsuba.splat.raster import rasterize


def flat(u, v, sd, op, sig, depth):
    """Isotropic 2D Gaussians, std ``sd`` pixels."""
    f = lambda a: B.Float(np.float32(a))  # noqa: E731
    var = np.asarray(sd, float) ** 2
    return Projected(u=f(u), v=f(v), conic_a=f(1 / var), conic_b=f(np.zeros_like(var)), conic_c=f(1 / var),
                     cov_uu=f(var), cov_vv=f(var), opacity=f(op), signal=f(sig), depth=f(depth))


def test_front_to_back_compositing_closed_form(variant):
    # Two Gaussians centred on pixel (row 5, column 10); the nearer one (depth 1)
    # first: I = a1 s1 + (1 - a1) a2 s2 at the centre, whatever the input order.
    p = flat(u=[10, 10], v=[5, 5], sd=[2, 3], op=[0.5, 0.8], sig=[2.0, 1.0], depth=[3.0, 1.0])
    img = rasterize(p, views=1, height=16, width=24).numpy().reshape(16, 24)
    assert img[5, 10] == pytest.approx(0.8 * 1.0 + 0.2 * 0.5 * 2.0, rel=1e-6)
    # One pixel to the right: alphas fall off as exp(-1/(2 sd^2)).
    a1, a2 = 0.8 * math.exp(-1 / 18), 0.5 * math.exp(-1 / 8)
    assert img[5, 11] == pytest.approx(a1 * 1.0 + (1 - a1) * a2 * 2.0, rel=1e-5)


def test_clamp_threshold_and_wrap(variant):
    # Opacity 1 on a pixel centre clamps to 0.99; a centre at column 0.2 also
    # lights the last column (azimuth wraps); far out alpha < 1/255 is skipped.
    p = flat(u=[5.0], v=[3], sd=[1.0], op=[1.0], sig=[1.0], depth=[1.0])
    img = rasterize(p, views=1, height=8, width=32).numpy().reshape(8, 32)
    assert img[3, 5] == pytest.approx(0.99, rel=1e-6)
    p = flat(u=[0.2], v=[3], sd=[1.0], op=[0.9], sig=[1.0], depth=[1.0])
    img = rasterize(p, views=1, height=8, width=32).numpy().reshape(8, 32)
    assert img[3, 0] == pytest.approx(0.9 * math.exp(-0.5 * 0.04), rel=1e-5)
    assert img[3, 31] == pytest.approx(0.9 * math.exp(-0.5 * 1.2**2), rel=1e-5)
    assert img[3, 4] == 0.0  # alpha = 0.9 exp(-0.5 * 3.8^2) ~ 6e-4 < 1/255


def test_gradient_of_signal_and_opacity(variant):
    p = flat(u=[6, 7], v=[4, 4], sd=[1.5, 2.0], op=[0.6, 0.7], sig=[1.0, 3.0], depth=[1.0, 2.0])
    for x in (p.opacity, p.signal):
        dr.enable_grad(x)
    img = rasterize(p, views=1, height=8, width=16)
    pix = 4 * 16 + 6  # row 4, column 6: first Gaussian's centre
    dr.backward(dr.gather(B.Float, img, B.UInt32(pix)))
    a1 = 0.6
    a2 = 0.7 * math.exp(-1 / 8)
    # I = a1 s1 + (1 - a1) a2 s2
    assert dr.grad(p.signal).numpy() == pytest.approx([a1, (1 - a1) * a2], rel=1e-5)
    assert dr.grad(p.opacity).numpy() == pytest.approx(
        [1.0 - a2 * 3.0, (1 - a1) * math.exp(-1 / 8) * 3.0], rel=1e-5)


@pytest.mark.parametrize("tile_lanes", [8, 32, 64])
def test_every_lane_layout_draws_the_same_image_and_gradients(variant, tile_lanes):
    # Random Gaussians over two views of 20 x 40 (partial tiles at the edges, the wrap);
    # the layout of lanes over a tile changes only float32 summation order.
    rng = np.random.default_rng(7)
    n, views, h, w = 60, 2, 20, 40
    m = views * n  # view-major: each view has its own n projected Gaussians
    args = (rng.uniform(0, w, m), rng.uniform(0, h, m), rng.uniform(0.8, 4.0, m), rng.uniform(0.3, 0.95, m),
            rng.uniform(0.1, 1.0, m), rng.uniform(0.5, 5.0, m))
    weights = B.Float(np.float32(rng.normal(size=views * h * w)))

    def draw(lanes):
        p = flat(*args)
        for x in (p.u, p.v, p.conic_a, p.opacity, p.signal):
            dr.enable_grad(x)
        img = rasterize(p, views=views, height=h, width=w, tile_lanes=lanes)
        dr.backward(dr.sum(img * weights))
        return img.numpy(), [dr.grad(x).numpy() for x in (p.u, p.v, p.conic_a, p.opacity, p.signal)]

    img16, grads16 = draw(16)
    img, grads = draw(tile_lanes)
    assert img16.max() > 0.1
    np.testing.assert_allclose(img, img16, atol=1e-6)
    for g, g16 in zip(grads, grads16):
        np.testing.assert_allclose(g, g16, atol=1e-5 * np.abs(g16).max())


def test_lane_layout_errors(variant, monkeypatch):
    p = flat([5.0], [4.0], [1.0], [0.5], [1.0], [1.0])
    with pytest.raises(ValueError, match="tile_lanes must be one of"):
        rasterize(p, views=1, height=8, width=16, tile_lanes=12)
    with pytest.raises(ValueError, match="tile_lanes must be one of"):
        rasterize(p, views=1, height=8, width=16, tile_lanes=True)
    for bad in ("4", "sixteen", "\u00b2"):   # "²" passes str.isdigit() but not int()
        monkeypatch.setenv("RFMITSUBA_SPLAT_LANES", bad)
        with pytest.raises(ValueError, match=f"RFMITSUBA_SPLAT_LANES must be one of .*{bad}"):
            rasterize(p, views=1, height=8, width=16)


def test_exp2_relative_error_and_clamp(variant):
    # The rasteriser's 2^x (range reduction and a degree-5 polynomial) against float64 NumPy
    # over its whole range, densely near 0 where the alphas that matter live.
    x = np.concatenate([np.linspace(-126.0, 127.0, 200_001), np.linspace(-12.0, 0.0, 100_001),
                        [-0.5, 0.5, -1.5, 2.5, -125.9999]]).astype(np.float32)
    got = raster._exp2(B.Float(x)).numpy().astype(np.float64)
    want = np.exp2(x.astype(np.float64))
    assert np.abs(got / want - 1).max() < 2.5e-7
    # Outside [-126, 127] it is clamped: finite, and tiny enough below to be skipped.
    out = raster._exp2(B.Float(np.float32([-1000.0, -127.5, 127.5, 1000.0]))).numpy()
    assert out.tolist() == [2.0**-126, 2.0**-126, 2.0**127, 2.0**127]


def test_moments_give_the_per_pixel_gradients(variant):
    # The backward pass sums seven moments per pair and turns them into gradients per Gaussian
    # (_moments_to_grads); summed per pixel from the definition instead, they must agree.
    rng = np.random.default_rng(5)
    k = 64
    du, dv = rng.uniform(-4, 4, k), rng.uniform(-4, 4, k)
    g_alpha, g_s = rng.normal(size=k), rng.normal(size=k)
    a, b, c, op = 0.7, -0.2, 0.4, 0.6
    gauss = np.exp(-0.5 * (a * du * du + 2 * b * du * dv + c * dv * dv))
    alpha = op * gauss
    want = [np.sum(g_alpha * alpha * (a * du + b * dv)), np.sum(g_alpha * alpha * (b * du + c * dv)),
            np.sum(-0.5 * g_alpha * alpha * du * du), np.sum(-g_alpha * alpha * du * dv),
            np.sum(-0.5 * g_alpha * alpha * dv * dv), np.sum(g_alpha * gauss), np.sum(g_s)]
    e = g_alpha * gauss
    moments = [np.sum(x) for x in (e, e * du, e * dv, e * du * du, e * du * dv, e * dv * dv, g_s)]
    got = raster._moments_to_grads(moments, a, b, c, op)
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_moment_mode(variant):
    # LLVM: Dr.Jit's choice, a copy of the accumulators per thread below its expand threshold
    # (lanes of one packet, and both threads, may add to one Gaussian); the warp reduction on CUDA.
    assert raster._moment_mode() == (dr.ReduceMode.Local if B.is_cuda() else dr.ReduceMode.Auto)


def test_gradients_do_not_depend_on_the_scatter_mode(variant):
    # Above Dr.Jit's expand threshold the moments are added with atomics instead of per-thread
    # copies: the same gradients up to float32 summation order.
    import drjit as dr

    from rfmitsuba.splat.project import Projected

    rng = np.random.default_rng(4)
    views, n, h, w = 2, 60, 24, 48
    f = lambda a: B.Float(np.float32(a))  # noqa: E731
    m = views * n
    sig2 = rng.uniform(1.0, 9.0, m)
    p = Projected(u=f(rng.uniform(0, w, m)), v=f(rng.uniform(0, h, m)), conic_a=f(1 / sig2), conic_b=f(np.zeros(m)),
                  conic_c=f(1 / sig2), cov_uu=f(sig2), cov_vv=f(sig2), opacity=f(rng.uniform(0.1, 0.9, m)),
                  signal=f(rng.uniform(0.0, 1.0, m)), depth=f(rng.uniform(0.5, 5.0, m)))
    weights = B.Float(np.float32(rng.normal(size=views * h * w)))

    def grads():
        args = [B.Float(getattr(p, k)) for k in ("u", "v", "conic_a", "conic_b", "conic_c", "opacity", "signal")]
        for a in args:
            dr.enable_grad(a)
        q = Projected(u=args[0], v=args[1], conic_a=args[2], conic_b=args[3], conic_c=args[4], cov_uu=p.cov_uu,
                      cov_vv=p.cov_vv, opacity=args[5], signal=args[6], depth=p.depth)
        dr.backward(dr.sum(raster.rasterize(q, views=views, height=h, width=w) * weights))
        return [np.asarray(dr.grad(a).numpy()) for a in args]

    expanded = grads()
    before = dr.expand_threshold()
    dr.set_expand_threshold(1)
    try:
        atomic = grads()
    finally:
        dr.set_expand_threshold(before)
    for a, b in zip(atomic, expanded):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6 * float(np.abs(b).max()))


def test_culled_tile_pairs_change_nothing(variant):
    # Lists built with the conic leave out the pairs whose tile the 1/255 ellipse misses: they
    # add nothing to any pixel, so the image keeps its bits and every gradient its value (the
    # per-Gaussian sums add in another order: float32 rounding). Tilted, elongated and sharp
    # Gaussians, some across the azimuth seam, two views.
    rng = np.random.default_rng(12)
    views, n, h, w = 2, 80, 26, 64
    m = views * n
    ang = rng.uniform(0, np.pi, m)
    s1, s2 = rng.uniform(0.4, 5.0, m), rng.uniform(0.4, 5.0, m)
    var_u = np.cos(ang) ** 2 * s1**2 + np.sin(ang) ** 2 * s2**2
    var_v = np.sin(ang) ** 2 * s1**2 + np.cos(ang) ** 2 * s2**2
    cov_uv = np.sin(ang) * np.cos(ang) * (s1**2 - s2**2)
    det = var_u * var_v - cov_uv**2
    f = lambda a: B.Float(np.float32(a))  # noqa: E731
    u = np.concatenate([rng.uniform(0, w, m - 6), [0.3, w - 0.4, 1.0, w - 1.2, 0.0, w / 2]])
    p = Projected(u=f(u), v=f(rng.uniform(-3, h + 3, m)), conic_a=f(var_v / det), conic_b=f(-cov_uv / det),
                  conic_c=f(var_u / det), cov_uu=f(var_u), cov_vv=f(var_v), opacity=f(rng.uniform(0.05, 0.99, m)),
                  signal=f(rng.uniform(-0.5, 2.0, m)), depth=f(rng.uniform(0.5, 5.0, m)))
    weights = B.Float(np.float32(rng.normal(size=views * h * w)))
    fields = [dr.detach(getattr(p, k)) for k in ("u", "v", "cov_uu", "cov_vv", "opacity", "depth")]
    conic = tuple(dr.detach(x) for x in (p.conic_a, p.conic_b, p.conic_c))

    def draw(lists):
        args = [dr.detach(getattr(p, k)) for k in ("u", "v", "conic_a", "conic_b", "conic_c", "opacity", "signal")]
        for a in args:
            dr.enable_grad(a)
        img = dr.custom(raster.Rasterize, *args, lists, views, h, w, tiles.lanes_per_tile())
        dr.backward(dr.sum(img * weights))
        return img.numpy(), [dr.grad(a).numpy() for a in args]

    full = tiles.build(*fields, views=views, n=n, height=h, width=w)
    culled = tiles.build(*fields, views=views, n=n, height=h, width=w, conic=conic)
    assert culled.offsets.numpy()[-1] < 0.95 * full.offsets.numpy()[-1]
    img_full, grads_full = draw(full)
    img_culled, grads_culled = draw(culled)
    assert img_full.max() > 0.1
    np.testing.assert_array_equal(img_culled, img_full)
    for g, g_full in zip(grads_culled, grads_full):
        np.testing.assert_allclose(g, g_full, rtol=1e-5, atol=1e-6 * float(np.abs(g_full).max()))


@pytest.mark.parametrize("views,height,width", [(1, 90, 360), (4, 90, 360), (3, 8, 8), (2, 24, 40), (5, 17, 9),
                                                (2, 8, 24), (2, 8, 8 * 2100)])    # the last: sorted
def test_lanes_take_tiles_in_pairs_of_equal_lists_view_by_view(variant, views, height, width):
    # The lane -> tile map is a permutation of the tiles (every tile drawn once, by its
    # tile_lanes lanes). Each view's tiles go in pairs of neighbours in list-length order (one
    # packet walks both lists), the pairs alternately (snake order) to the two halves of the
    # lanes, and each half holds the views in order (the backward pass's accumulators of one
    # view at a time).
    nty, ntx = tiles.tile_grid(height, width)
    per_view = nty * ntx
    num = views * per_view
    rng = np.random.default_rng(views * 1000 + height)
    lengths = rng.integers(0, 5000, num).astype(np.uint32)     # some beyond the sort's levels
    lengths[rng.random(num) < 0.2] = 0
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.uint32)
    lanes = tiles.lanes_per_tile()
    slot_tile = raster._slot_tiles(B.UInt32(offsets), views, per_view)
    tile = raster._lanes(slot_tile, views, height, width, lanes)[0].numpy()
    slots = tile[::lanes]
    assert np.all(tile.reshape(-1, lanes) == slots[:, None])
    assert sorted(slots.tolist()) == list(range(num))
    first = raster._first_half_tiles(per_view)
    assert abs(2 * first - per_view) <= 2
    sizes = [first if v % 2 == 0 else per_view - first for v in range(views)]   # the first half's
    halves = (slots[:sum(sizes)], slots[sum(sizes):])
    for half, size in zip(halves, (sizes, [per_view - s for s in sizes])):
        assert np.all(np.diff(half // per_view) >= 0)                       # view after view
        assert np.bincount(half // per_view, minlength=views).tolist() == size
    assert abs(len(halves[0]) - len(halves[1])) <= 2
    # packet partners: neighbours in the view's length order (exact lengths when counted by the
    # rank loop, clamped at the sort's levels beyond)
    key = lengths if per_view <= raster._RANK_LOOP_MAX else np.minimum(lengths, raster._LENGTH_LEVELS - 1)
    for v in range(views):
        ranks = np.empty(per_view, np.int64)
        ranks[np.argsort(key[v * per_view:(v + 1) * per_view], kind="stable")] = np.arange(per_view)
        rank_of = dict(zip(range(v * per_view, (v + 1) * per_view), ranks))
        for half in halves:
            mine = [t for t in half.tolist() if t // per_view == v]
            pairs = [mine[i:i + 2] for i in range(0, len(mine), 2)]
            for pair in pairs:
                r = sorted(rank_of[t] for t in pair)
                assert r[0] % 2 == 0 and (len(r) == 1 or r[1] == r[0] + 1)
    if per_view >= 8:   # the snake order splits the work about evenly
        work = [int(key[h].sum()) for h in halves]
        assert abs(work[0] - work[1]) <= 0.25 * sum(work)
