"""rfmitsuba.train.pursuit: coherent plane pursuit for an unknown room's field.

The candidate score is checked against finite differences of the training loss; a wall planted
0.3 m from the fixed transmitter (its image within the array's beam of the direct path, where the
directional scan cannot see it) is found; adding images leaves the rendered PAS unchanged and
moves the optimizer's moments with their parameters; a grown field survives a state round trip."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

F = 2.4e9
pytestmark = pytest.mark.usefixtures("one_thread")


def _field(planes=(), gains=()):
    """Direct path (gain 1) plus single reflections across ``planes`` ((axis, offset) pairs) with ``gains``."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField
    from rfmitsuba.train.pursuit import reflection

    maps = [reflection(a, o) for a, o in planes]
    A = np.stack([np.eye(3)] + [m[0] for m in maps])
    f = CoherentGaussianField(A, np.array([0] + [1] * len(maps)), np.zeros((0, 3)),
                              cfg=CoherentGaussianConfig(vis_grid=(2, 2, 2)), readout="amplitude", wavefront="plane",
                              vis_center=np.array([2.0, 2.0, 1.1]), frequency_hz=F, init="data")
    f.params["img_offset"] = B.Float(np.concatenate([np.zeros(3)] + [m[1] for m in maps]).astype(np.float32))
    f.params["img_amp"] = B.Float(np.concatenate([[1.0, 0.0]] + [[g, 0.3 * g] for g in gains]).astype(np.float32))
    f.params["vis_grid_box"] = B.Float(np.array([0.8, 0.8, 0.6, 3.5, 3.0, 1.6], np.float32))
    return f


def _data(truth, n=48, seed=0, d=2):
    """Moving-RX stub data: the fixed transmitter in a corner at (0.3, 0.3, 2.0) m, 0.3 m from the
    wall x = 0; receivers 0.8-3.5 m from it; PAS rendered by ``truth``."""
    from rfmitsuba.models.base import Views, render

    rng = np.random.default_rng(seed)
    q = np.c_[rng.uniform(0.8, 3.5, n), rng.uniform(0.8, 3.0, n), rng.uniform(0.6, 1.6, n)]
    y = np.tile([0.3, 0.3, 2.0], (n, 1))
    data = SimpleNamespace(path="stub", train=np.arange(n), rx_to_world=None, frequency_hz=F, task="rx",
                           positions=lambda idx: (q[idx], y[idx], q[idx]))
    views = Views.of(data, np.arange(n))
    pas = render([truth], views, height=90 // d, width=360 // d).numpy()
    data.pas = lambda idx, d=d: np.asarray(pas)[np.asarray(idx)]
    return data


def _pursuit(data, *, planes=1, views=48):
    from rfmitsuba.train.loss import loss
    from rfmitsuba.train.pursuit import PlanePursuit

    return PlanePursuit(data=data, fit=np.arange(len(data.train)), frozen=[], downsample=2, prefix="bg.",
                        iterations=100, planes=planes, at=(0.5,), views=views, loss_fn=loss)


def _adam(field):
    from drjit.opt import Adam

    opt = Adam(lr=1e-3)
    for k, v in field.trainable().items():
        opt["bg." + k] = v
    return opt


def test_candidates_lie_beyond_the_positions_and_picks_keep_apart():
    from rfmitsuba.train.pursuit import pick_planes, plane_candidates

    axis, off = plane_candidates(np.array([[0.3, 1.0, 0.5], [2.0, 3.0, 2.0]]), step=0.5, margin=1.0)
    assert sorted(off[axis == 0].tolist()) == [-0.7, -0.2, 2.5, 3.0]
    assert sorted(off[axis == 2].tolist()) == [-0.5, 0.0, 2.5, 3.0]
    score = np.array([5.0, 4.9, 4.0, 3.0, 2.5, 2.0, -1.0])
    ax = np.array([0, 0, 1, 0, 0, 2, 2])
    of = np.array([0.0, 0.1, 0.0, 1.0, 1.2, 3.0, 0.0])
    # 1 is 0.1 m from the pick 0 on x (min_separation 0.3); 3 is 0.05 m from the field's plane
    # x = 1.05 (existing_separation 0.08), 4 is 0.15 m from it: a misplaced plane does not hide
    # the wall beside it; 6 scores below zero
    got = pick_planes(score, ax, of, count=7, existing_axis=np.array([0]), existing_offset=np.array([1.05]))
    assert got == [0, 2, 4, 5]
    got = pick_planes(score, ax, of, count=7, existing_axis=np.array([0]), existing_offset=np.array([1.05]),
                      existing_separation=0.3)
    assert got == [0, 2, 5]


def test_new_images_are_the_single_and_double_reflections():
    from rfmitsuba.train.pursuit import new_images

    f = _field(planes=[(1, 4.0)], gains=[0.5])
    A, b, order = new_images(f, [(0, 0.0), (2, 3.0)], max_order=2)
    y = np.array([0.3, 0.3, 2.0])
    pts = {tuple(np.round(a @ y + c, 6)): o for a, c, o in zip(A, b, order)}
    assert pts[(-0.3, 0.3, 2.0)] == 1 and pts[(0.3, 0.3, 4.0)] == 1
    assert pts[(-0.3, 7.7, 2.0)] == 2              # across x = 0 and the field's y = 4 (they commute: once)
    assert pts[(-0.3, 0.3, 4.0)] == 2              # across the two new planes
    assert pts[(0.3, 7.7, 4.0)] == 2
    assert len(pts) == len(A) == 2 + 3             # perpendicular pairs commute, each image once
    A1, _, _ = new_images(f, [(0, 0.0)], max_order=1)
    assert len(A1) == 1


def test_candidate_score_is_the_derivative_of_the_training_loss():
    """d loss / d (gain of a candidate image) from :meth:`image_gain_gradients` and the
    pursuit's loss gradient, against central differences of the training loss with the
    candidate added (unwindowed) at a small gain. The field has two paths, not one: a lone
    path's PAS has exact nulls, where the min-max normalisation's minimum has a kink."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.models.base import Views, render
    from rfmitsuba.train.loss import loss
    from rfmitsuba.train.pursuit import reflection

    data = _data(_field(planes=[(0, 0.0)], gains=[0.7]), n=8)
    field = _field(planes=[(1, 4.0)], gains=[0.5])
    pur = _pursuit(data, views=8)
    gr, gi = pur.loss_gradient(field)
    views = Views.of(data, np.arange(8))
    A, b = reflection(0, -0.05)
    g = field.image_gain_gradients(views, gr, gi, A[None], b[None])[0]
    gt = B.TensorXf(data.pas(np.arange(8)))

    def L(re, im):
        f = _field(planes=[(1, 4.0), (0, -0.05)], gains=[0.5, 0.0])
        f.params["img_amp"] = B.Float(np.array([1.0, 0.0, 0.5, 0.15, re, im], np.float32))
        f.params["vis_log_extent"] = B.Float(np.array([np.log(5.0), np.log(5.0), 30.0], np.float32))
        with dr.suspend_grad():
            return float(loss(render([f], views, height=45, width=180), gt).numpy()[0])

    # small: the min-max normalisation's extremes switch pixels within a few 1e-3 of gain (at
    # eps = 1e-3 the difference quotient was 0.045, at 3e-3 0.038, at 1e-4 and 3e-4 0.047 = g)
    eps = 1e-4
    fd = [(L(eps, 0) - L(-eps, 0)) / (2 * eps), (L(0, eps) - L(0, -eps)) / (2 * eps)]
    assert np.abs(fd).max() > 1e-3                       # not a trivial zero
    assert np.allclose(g, fd, rtol=0.02, atol=0.01 * np.abs(fd).max()), (g, fd)


def test_pursuit_finds_a_wall_next_to_the_fixed_transmitter_and_changes_nothing_at_insertion():
    import drjit as dr

    from rfmitsuba.models.base import Views, render

    # The grown field carries a second path (a wall at y = 4 m) besides the direct one: a lone
    # path's PAS has exact nulls, where the gradient of |sum| points anywhere, and channel errors
    # of 1e-5 (CUDA's fast sine, float32 sums in another order) then move the best candidate from
    # the wall to planes on other axes. With two paths the wall wins by 13% also with 1e-4 errors.
    data = _data(_field(planes=[(0, 0.0), (1, 4.0)], gains=[0.7, 0.6]))
    field = _field(planes=[(1, 4.0)], gains=[0.6])
    opt = _adam(field)
    # give the old parameters distinctive Adam moments to follow through the growth
    for key, (value, promoted, lr, (t, m, v, vmax)) in list(opt.state.items()):
        n = dr.width(value)
        opt.state[key] = (value, promoted, lr, (t, type(m)(np.arange(1, n + 1, dtype=np.float32)), v, vmax))
    views = Views.of(data, np.arange(6))
    before = render([field], views, height=45, width=180).numpy()
    pur = _pursuit(data)
    assert not pur.step_end(49, field, opt)               # not a pursuit step
    assert pur.step_end(50, field, opt)
    event = pur.history[0]
    assert event["planes"][0]["axis"] == "x" and abs(event["planes"][0]["offset_m"]) <= 0.1, event
    assert field.num_images == 4 and event["images_added"] == 2   # the wall, and its double with y = 4
    after = render([field], views, height=45, width=180).numpy()
    assert np.allclose(before, after, atol=1e-6)
    m_amp = np.asarray(opt.state["bg.img_amp"][3][1].numpy())
    assert m_amp.tolist() == [1, 2, 3, 4, 0, 0, 0, 0]     # old moments kept, the new images' are zero
    m_grid = np.asarray(opt.state["bg.vis_grid"][3][1].numpy())
    assert m_grid[:16].tolist() == list(range(1, 17)) and not m_grid[16:].any()
    assert not pur.step_end(50, field, opt)               # once per step, also after a resume
    state = pur.state_dict()
    again = _pursuit(data)
    again.load_state_dict(state)
    assert not again.step_end(50, field, opt)


def test_a_grown_field_round_trips(tmp_path):
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.base import Views, load_field, render
    from rfmitsuba.train.pursuit import reflection

    field = _field()
    A, b = reflection(1, 3.5)
    field.add_images(A[None], b[None], np.array([1]), vis_center=np.array([2.0, 2.0, 1.2]))
    field.params["img_amp"] = type(field.params["img_amp"])(np.array([1, 0, 0.4, 0.1], np.float32))
    path = field.save(tmp_path / "f.npz")
    back = load_field(path)
    assert back.num_images == 2 and np.allclose(back.A, field.A)
    fresh = _field()                                       # a checkpoint of a grown field loads into the initial one
    fresh.load_state_dict(field.state_dict())
    data = _data(_field(), n=4)
    views = Views.of(data, np.arange(4))
    ref = render([field], views, height=45, width=180).numpy()
    assert np.allclose(render([fresh], views, height=45, width=180).numpy(), ref, atol=1e-6)
    assert np.allclose(render([back], views, height=45, width=180).numpy(), ref, atol=1e-6)
    with pytest.raises(ConfigError, match="2 maps need 2 finite offsets"):
        field.add_images(np.stack([A, A]), b[None], np.array([1, 1]), vis_center=np.zeros(3))


def test_only_an_unknown_rooms_field_with_the_pursuit_on_gets_one():
    import dataclasses

    from rfmitsuba.train.loss import loss
    from rfmitsuba.train.pursuit import PlanePursuit, pursuit_for

    data = _data(_field(), n=4)
    kw = dict(data=data, fit=np.arange(4), frozen=[], downsample=2, prefix="bg.", iterations=100, loss_fn=loss)
    field = _field()
    field.cfg = dataclasses.replace(field.cfg, pursuit_planes=0)
    assert pursuit_for(field, **kw) is None
    field.cfg = dataclasses.replace(field.cfg, pursuit_planes=2, pursuit_at=(0.2, 0.6))
    got = pursuit_for(field, **kw)
    assert isinstance(got, PlanePursuit) and got.steps == [20, 60]
    # "auto": off for tags in a patch 5 m from a fixed gateway (within the array's beam)
    rng = np.random.default_rng(0)
    tags = np.c_[rng.uniform(1.0, 2.6, 4), rng.uniform(0.5, 1.8, 4), rng.uniform(0.5, 1.4, 4)]
    gateway = np.tile([7.0, 1.2, 1.0], (4, 1))
    patch = dict(kw, data=SimpleNamespace(**{**vars(data), "task": "tx",
                                             "positions": lambda idx: (gateway[idx], tags[idx], tags[idx])}))
    assert pursuit_for(field, **patch) is None
    field.cfg = dataclasses.replace(field.cfg, pursuit="on")
    assert isinstance(pursuit_for(field, **patch), PlanePursuit)
    field.cfg = dataclasses.replace(field.cfg, pursuit="off")
    assert pursuit_for(field, **kw) is None
    field.cfg = dataclasses.replace(field.cfg, pursuit="on")
    field.init = "room"
    assert pursuit_for(field, **kw) is None


def test_a_run_killed_after_a_pursuit_resumes_to_the_same_field(tmp_path):
    """An unknown room (a NeRF2 folder, no scene) with a pursuit at step 12: stopped at step 25
    (last checkpoint: step 20, after the pursuit) and run again, it ends with the uninterrupted
    run's grown geometry and parameters, and its summary lists the pursuit once."""
    import json

    from stage1_data import make_dataset

    from rfmitsuba.core import config as C
    from rfmitsuba.data import nerf2
    from rfmitsuba.data.store import open_dataset
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.config import TrainConfig
    from rfmitsuba.train.trainer import Trainer

    folder = nerf2.write(open_dataset(make_dataset(tmp_path / "tx", num_antennas=30, task="tx")), tmp_path / "n")
    data = TrainData.open(folder)
    cfg = C.override(TrainConfig(), ['model="coherent_gaussians"', "iterations=40", "downsample=5", "val_every=10",
                                     "checkpoint_every=10", "log_every=5", "val_fraction=0.1", "threads=1",
                                     "coherent_gaussians.images=2", "coherent_gaussians.scatterers=2",
                                     "coherent_gaussians.pursuit_at=[0.3]", 'coherent_gaussians.frame_search="off"',
                                     'coherent_gaussians.pursuit="on"'])   # a moving-TX folder: off by default
    a, b = tmp_path / "a", tmp_path / "b"
    sa = Trainer(cfg, data, a, quiet=True).run()
    assert Trainer(cfg, data, b, quiet=True).run(stop_at=25)["stopped"] == "stop_at"
    assert json.loads((b / "checkpoint" / "meta.json").read_text())["step"] == 20
    sb = Trainer(cfg, data, b, quiet=True).run()
    assert [e["step"] for e in sa["density_events"]] == [e["step"] for e in sb["density_events"]] == [12]
    assert sa["num_gaussians"] == sb["num_gaussians"] > 1 + 2 * 2 + 2    # grown beyond the scan's field
    with np.load(a / "final" / "field.npz") as za, np.load(b / "final" / "field.npz") as zb:
        np.testing.assert_array_equal(za["geometry.A"], zb["geometry.A"])
        for k in ("img_offset", "img_amp", "vis_center", "cal"):
            np.testing.assert_allclose(za[k], zb[k], rtol=1e-3, atol=1e-4, err_msg=k)
