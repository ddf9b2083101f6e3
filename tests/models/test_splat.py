"""Tests of rfmitsuba.models.splat: initialisation, evaluation layout, state, PLY export, concat."""
from __future__ import annotations

import numpy as np
import pytest


def _square_meshes():
    """Two triangles in the plane z = 1: one of area 0.5 (x in [0,1]) and one of area 2 (x in [2,4])."""
    v1 = np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1]], float)
    v2 = np.array([[2, 0, 1], [4, 0, 1], [2, 2, 1]], float)
    f = np.array([[0, 1, 2]])
    return [(v1, f), (v2, f)]


def test_sample_surface_is_on_the_triangles_and_area_weighted():
    from rfmitsuba.models.splat import sample_surface

    pts = sample_surface(_square_meshes(), 20000, rng=np.random.default_rng(0))
    assert pts.shape == (20000, 3)
    np.testing.assert_allclose(pts[:, 2], 1.0)
    first = pts[:, 0] <= 1.0
    # inside the triangles: x + y <= 1 (first), (x - 2) + y <= 2 (second)
    assert np.all(pts[first, 0] + pts[first, 1] <= 1 + 1e-9)
    assert np.all(pts[~first, 0] - 2 + pts[~first, 1] <= 2 + 1e-9)
    # area fraction 0.5 / 2.5 = 0.2; binomial std ~ 0.003
    assert abs(first.mean() - 0.2) < 0.015


def test_knn_scale_of_a_grid():
    from rfmitsuba.models.splat import knn_scale

    g = np.stack(np.meshgrid(np.arange(5), np.arange(5), np.arange(5), indexing="ij"), -1).reshape(-1, 3) * 0.1
    s = knn_scale(g)
    # an interior point of a 0.1 m grid has 6 neighbours at 0.1 m
    assert abs(s[62] - 0.1) < 1e-9


def test_scene_meshes_of_the_bedroom_and_missing_file(tmp_path):
    from rfmitsuba import scenes
    from rfmitsuba.core.errors import SceneError
    from rfmitsuba.models.splat import scene_meshes

    ms = scene_meshes(scenes.path("bedroom"))
    assert len(ms) > 3 and all(v.shape[1] == 3 and f.shape[1] == 3 for v, f in ms)
    with pytest.raises(SceneError, match="does not exist"):
        scene_meshes(tmp_path / "nope.xml")
    bad = tmp_path / "bad.xml"
    bad.write_text('<scene><shape type="ply" id="w"><string name="filename" value="m/none.ply"/></shape></scene>')
    with pytest.raises(SceneError, match="none.ply"):
        scene_meshes(bad)


def _field(n=6, **kw):
    from rfmitsuba.models.nn import NetConfig
    from rfmitsuba.models.splat import SplatConfig, SplatField

    cfg = SplatConfig(init_scale=0.2, net=NetConfig(width=8, gaussian_octaves=1, antenna_octaves=1), **kw)
    pts = np.random.default_rng(0).uniform(0, 3, (n, 3))
    return SplatField.from_points(pts, cfg=cfg, box=np.array([[0, 0, 0], [3, 3, 3.0]]), seed=4)


def test_splats_layout_and_ranges(variant):
    f = _field()
    ap = np.array([[1.0, 1, 1], [2, 2, 1], [0.5, 2, 2]])
    s = f.splats(ap)
    assert (s.n, s.b) == (6, 3)
    op = s.opacities.numpy()
    sig = s.signals.numpy()
    assert op.shape == (18,) and sig.shape == (18,)
    assert np.all((op > 0) & (op < 1)) and np.all((sig > 0) & (sig < 1))
    np.testing.assert_allclose(np.array(s.means.numpy()).T, f.gaussians_numpy()["means"], atol=1e-6)
    q = np.array(s.rotations.numpy())
    np.testing.assert_allclose(np.linalg.norm(q, axis=0), 1, atol=1e-6)


def test_angular_scale_mode_scales_with_distance(variant):
    f = _field(scale_mode="angular")
    g = f.gaussians_numpy()
    vp = np.array([[0.0, 0, 0], [3, 3, 3.0]])
    s = f.splats(vp, view_pos=vp)
    ls = np.array(s.log_scales.numpy()).T.reshape(2, 6, 3)
    d = np.linalg.norm(g["means"][None] - vp[:, None], axis=2)
    np.testing.assert_allclose(ls[..., 0], g["log_scales"][None, :, 0] + np.log(d), atol=1e-5)


def test_state_dict_round_trip_and_freeze(variant, tmp_path):
    from rfmitsuba.models.splat import SplatField

    f = _field()
    f.save(tmp_path / "f.npz")
    g = SplatField.load(tmp_path / "f.npz")
    ap = np.array([[1.0, 2, 1]])
    a, b = f.splats(ap), g.splats(ap)
    np.testing.assert_array_equal(a.signals.numpy(), b.signals.numpy())
    np.testing.assert_array_equal(a.opacities.numpy(), b.opacities.numpy())
    assert g.num_parameters == f.num_parameters == 6 * 11 + f.net.num_parameters
    assert f.trainable()
    f.freeze()
    assert f.trainable() == {} and f.frozen
    with np.load(tmp_path / "f.npz", allow_pickle=False) as z:
        assert "meta" in z.files and "net.head" in z.files


def test_bad_gaussian_arrays_are_errors(variant):
    from rfmitsuba.core.errors import ConfigError

    f = _field()
    g = f.gaussians_numpy()
    bad = dict(g, means=g["means"][:, :2])
    with pytest.raises(ConfigError, match="means"):
        f.set_gaussians(bad)
    nan = dict(g, log_scales=g["log_scales"].copy())
    nan["log_scales"][0, 0] = np.nan
    with pytest.raises(ConfigError, match="non-finite"):
        f.set_gaussians(nan)
    with pytest.raises(KeyError, match="nope"):
        f.assign({"nope": None})


def test_ply_round_trip(variant, tmp_path):
    from rfmitsuba.models.splat import read_ply, write_ply

    f = _field()
    sig = np.linspace(0, 1, 6).astype(np.float32)
    write_ply(tmp_path / "g.ply", f, signal=sig)
    head = (tmp_path / "g.ply").read_bytes()[:600].decode("ascii", "replace")
    for prop in ["x", "y", "z", "scale_0", "scale_2", "rot_0", "rot_3", "opacity", "f_dc_0", "signal"]:
        assert f"property float {prop}\n" in head
    d = read_ply(tmp_path / "g.ply")
    g = f.gaussians_numpy()
    np.testing.assert_array_equal(np.stack([d["x"], d["y"], d["z"]], 1), g["means"])
    np.testing.assert_array_equal(d["scale_1"], g["log_scales"][:, 1])
    np.testing.assert_array_equal(d["opacity"], g["opacity_logits"])
    np.testing.assert_array_equal(d["signal"], sig)


def test_concat_interleaves_sets_view_major(variant):
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.splat import Splats

    def mk(n, b, base):
        per_view = B.Float(np.arange(n * b, dtype=np.float32) + base)
        shared = B.Float(np.arange(n, dtype=np.float32) + base)
        m = B.Array3f(shared, shared, shared)
        q = B.Array4f(shared, shared, shared, shared)
        return Splats(means=m, log_scales=m, rotations=q, opacities=per_view, signals=shared, n=n, b=b)

    s = Splats.concat([mk(3, 2, 0.0), mk(2, 2, 100.0)])
    assert (s.n, s.b) == (5, 2)
    # per-view arrays: view 0 -> [0,1,2,100,101], view 1 -> [3,4,5,102,103]
    np.testing.assert_array_equal(s.opacities.numpy(), [0, 1, 2, 100, 101, 3, 4, 5, 102, 103])
    # shared arrays stay shared (size N)
    np.testing.assert_array_equal(s.signals.numpy(), [0, 1, 2, 100, 101])
    np.testing.assert_array_equal(np.array(s.means.numpy())[0], [0, 1, 2, 100, 101])


@pytest.mark.parametrize("host", [False, True])
def test_a_training_step_compiles_once(variant, host):
    """Render, loss and backward of the splat field on fresh host arrays every step (positions,
    target images) compile their kernels once: every host array reaches Dr.Jit as an aligned upload
    (rfmitsuba.core.upload), whatever alignment NumPy gave it. ``host``: the EM network's products on
    the host's BLAS (LLVM) or as cooperative vectors."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.core.upload import upload
    from rfmitsuba.models.base import Views, render
    from rfmitsuba.models.nn import NetConfig
    from rfmitsuba.models.splat import SplatConfig, SplatField
    from rfmitsuba.train.loss import loss

    if host and B.is_cuda():
        pytest.skip("the host products run on the LLVM backend only")
    cfg = SplatConfig(init_scale=0.4, scale_mode="angular",
                      net=NetConfig(width=8, gaussian_octaves=1, antenna_octaves=1, host_products=host))
    pts = np.random.default_rng(0).uniform(0.5, 2.5, (40, 3))
    f = SplatField.from_points(pts, cfg=cfg, box=np.array([[0, 0, 0], [3, 3, 3.0]]), seed=4)
    for v in f.trainable().values():
        dr.enable_grad(v)
    rng = np.random.default_rng(1)
    keep, misses = [], []
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        for step in range(7):
            dr.kernel_history()
            q = rng.uniform(0.5, 2.5, (3, 3))
            views = Views(antenna_pos=q, view_pos=q, transmitter=np.full((3, 3), 1.5), rx_to_world=None,
                          frequency_hz=5.0e9)
            img = render([f], views, height=18, width=72)
            gt = upload(B.TensorXf, rng.random((3, 18, 72)))
            value = loss(img, gt)
            dr.backward(value)
            dr.eval(value, [dr.grad(v) for v in f.trainable().values()])
            misses.append(sum(1 for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT
                              and not k["cache_hit"]))
            for v in f.trainable().values():
                dr.clear_grad(v)
            keep.append(np.empty(5 + 7 * step, np.float32))      # the heap moves
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert misses[2:] == [0] * 5, misses
