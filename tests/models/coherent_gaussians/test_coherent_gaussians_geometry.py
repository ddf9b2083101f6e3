"""rfmitsuba.models.coherent_gaussians.geometry: the data's geometry (how widely the positions
spread) and the room's (a room box as reflections, reflections composed into image sources).

Positions within the array's beam get the scan, wider ones the pursuit; the default visibility grid
follows the room and how densely the positions lie; a room box's six walls (and their double
reflections) join the scanned planes, with the outside-the-box test that training and prediction
share; composed reflections give a room's double images, each once."""
from __future__ import annotations

import numpy as np
import pytest
from coherent_gaussians_cases import _stub_training_data


#: every test on one Dr.Jit thread (the ``one_thread`` fixture of tests/conftest.py)
pytestmark = pytest.mark.usefixtures("one_thread")


def test_compose_images_builds_a_rooms_double_reflections():
    """Two parallel walls x = 0 and x = 4 and a floor z = 0, order 2: the direct path, 3 single and
    the double images (across both x walls, two orders; across a wall and the floor, two), each once."""
    from rfmitsuba.models.coherent_gaussians import compose_images

    A = np.stack([np.diag([-1.0, 1, 1]), np.diag([-1.0, 1, 1]), np.diag([1.0, 1, -1])])
    b = np.array([[0.0, 0, 0], [8.0, 0, 0], [0, 0, 0]])
    A2, b2, order = compose_images(A, b, max_order=2)
    assert list(np.bincount(order)) == [1, 3, 4]  # perpendicular reflections commute: one image each
    y = np.array([1.0, 2.0, 0.5])
    imgs = {tuple(np.round(a @ y + c, 6)) for a, c in zip(A2, b2)}
    assert len(imgs) == len(A2)
    assert (9.0, 2.0, 0.5) in imgs and (-7.0, 2.0, 0.5) in imgs and (-1.0, 2.0, -0.5) in imgs
    assert len(compose_images(A, b, max_order=1)[0]) == 4


def test_dense_unknown_rooms_get_the_finer_visibility_grid(monkeypatch):
    """vis_grid = "auto": (8, 8, 4) for an unknown room with DENSE_POSITIONS distinct training
    positions or more, (4, 4, 2) below that and for a known room at any count; a grid set in the
    config is kept. Only the fine grid advises DENSE_EPOCHS passes over the data."""
    from rfmitsuba.core import config as C
    from rfmitsuba.models import coherent_gaussians as cg
    from rfmitsuba.models.coherent_gaussians import field, geometry
    from rfmitsuba.train.config import TrainConfig

    assert cg.default_vis_grid(init="data", num_positions=geometry.DENSE_POSITIONS) == geometry.DENSE_VIS_GRID \
        == (8, 8, 4)
    assert cg.default_vis_grid(init="data", num_positions=geometry.DENSE_POSITIONS - 1) == cg.DEFAULT_VIS_GRID
    assert cg.default_vis_grid(init="room", num_positions=10 * geometry.DENSE_POSITIONS) == cg.DEFAULT_VIS_GRID
    monkeypatch.setattr(geometry, "DENSE_POSITIONS", 10)     # the stub's 10 positions count as dense
    data, _, _ = _stub_training_data(10, seed=1)
    small = ['model="coherent_gaussians"', "coherent_gaussians.images=2", "coherent_gaussians.scatterers=4"]
    f = cg.CoherentGaussianField.for_training(C.override(TrainConfig(), small), data, scene_xml=None)
    assert f.cfg.vis_grid == (8, 8, 4) and f.grid_cells == 256
    g = cg.CoherentGaussianField.for_training(C.override(TrainConfig(), small + ["coherent_gaussians.vis_grid=[2,2,2]"]),
                                              data, scene_xml=None)
    assert g.grid_cells == 8
    # the fine grid learns cell by cell: it asks for passes over the data (TrainConfig.epochs = "auto")
    assert f.epochs_advised == field.DENSE_EPOCHS == 40.0 and g.epochs_advised == 0.0


def test_outside_room_box_counts_faces_inside():
    """The one "outside the box" test that training (``room_box_planes``) and ``predict`` share:
    a point on a face is inside; a millimetre past any of the six faces is outside."""
    from rfmitsuba.models.coherent_gaussians import outside_room_box

    box = [0.0, 0.0, 0.0, 4.4, 3.5, 2.8]
    inside = np.array([[0.0, 0.0, 0.0], [4.4, 3.5, 2.8], [2.0, 1.0, 1.5]])
    assert not outside_room_box(box, inside).any()
    past = np.array([[-1e-3, 1, 1], [4.401, 1, 1], [1, -1e-3, 1], [1, 3.501, 1], [1, 1, -1e-3], [1, 1, 2.801]])
    assert outside_room_box(box, past).all()


def test_room_box_walls_join_the_scanned_planes():
    """An unknown room with known dimensions (``room_box``): the six walls' images, and their
    double reflections, join the scan's; a position outside the box, a malformed box, and a box
    beside a known room's XML are errors that name the problem."""
    from rfmitsuba.core import config as C
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianField, room_box_planes
    from rfmitsuba.scenes import path as scene_path
    from rfmitsuba.train.config import TrainConfig

    box = [0.0, 0.0, 0.0, 4.4, 3.5, 2.8]
    A, b = room_box_planes(box, np.array([[1.0, 1.0, 1.0]]))
    y = np.array([0.3, 0.4, 2.0])
    mirrored = {tuple(np.round(a @ y + c, 6)) for a, c in zip(A, b)}
    assert mirrored == {(-0.3, 0.4, 2.0), (8.5, 0.4, 2.0), (0.3, -0.4, 2.0), (0.3, 6.6, 2.0), (0.3, 0.4, -2.0),
                        (0.3, 0.4, 3.6)}
    with pytest.raises(ConfigError, match=r"position 1 at \[5.0, 1.0, 1.0\] m lies outside the room"):
        room_box_planes(box, np.array([[1.0, 1.0, 1.0], [5.0, 1.0, 1.0]]))

    data, q, ty = _stub_training_data(10, seed=2)
    small = ['model="coherent_gaussians"', "coherent_gaussians.images=0", "coherent_gaussians.scatterers=0",
             'coherent_gaussians.init="data"']
    plain = CoherentGaussianField.for_training(C.override(TrainConfig(), small), data, scene_xml=None)
    boxed = CoherentGaussianField.for_training(
        C.override(TrainConfig(), small + [f"coherent_gaussians.room_box={box}"]), data, scene_xml=None)
    assert plain.num_images == 1                          # the direct path alone
    # + the 6 walls, + their double reflections: 12 pairs of perpendicular walls (which commute, so
    # one image each) and 2 orders of each of the 3 pairs of parallel walls
    assert boxed.num_images == 1 + 6 + 12 + 6
    offsets = boxed.params["img_offset"].numpy().reshape(-1, 3)
    images = {tuple(np.round(a @ ty[0] + c, 6)) for a, c in zip(boxed.A, offsets)}
    assert (-0.3, 0.3, 2.0) in images and (0.3, 0.3, 3.6) in images and (-0.3, -0.3, 2.0) in images

    with pytest.raises(ConfigError, match="lies outside the room"):
        CoherentGaussianField.for_training(
            C.override(TrainConfig(), small + ["coherent_gaussians.room_box=[0, 0, 0, 1.5, 3.5, 2.8]"]), data,
            scene_xml=None)
    with pytest.raises(ConfigError, match="room_box: .* matches none of"):
        C.override(TrainConfig(), small + ["coherent_gaussians.room_box=[0, 0, 0, 4.4, 3.5]"])
    for bad in ("[1, 0, 0, 0.5, 3.5, 2.8]", "[0, 0, 0, 4.4, 3.5, nan]"):
        with pytest.raises(ConfigError, match="room_box must be 6 finite numbers"):
            C.override(TrainConfig(), small + [f"coherent_gaussians.room_box={bad}"])
    with pytest.raises(ConfigError, match="set coherent_gaussians.init=data"):
        CoherentGaussianField.for_training(
            C.override(TrainConfig(), small[:-1] + [f"coherent_gaussians.room_box={box}"]), data,
            scene_xml=scene_path("bedroom"))


def test_positions_within_the_beam_get_the_scan_and_wider_ones_the_pursuit():
    """A room walked around a corner device spreads 20-ish degrees (pursuit, no scanned planes);
    tags in a patch 5 m from the gateway a few degrees (scan, 12 planes); explicit settings win."""
    from types import SimpleNamespace

    from rfmitsuba.models.coherent_gaussians.geometry import (SCAN_PLANES, CoherentGaussianConfig, position_spread_deg,
                                                     scan_planes, spreads_wide, uses_pursuit)

    rng = np.random.default_rng(0)
    room = np.c_[rng.uniform(0.15, 4.25, 300), rng.uniform(0.15, 3.35, 300), rng.uniform(0.5, 2.0, 300)]
    tags = np.c_[rng.uniform(1.0, 2.6, 300), rng.uniform(0.5, 1.8, 300), rng.uniform(0.5, 1.4, 300)]
    corner, gateway = np.array([0.3, 0.3, 2.0]), np.array([7.0, 1.2, 1.0])
    assert 15 < position_spread_deg(corner, room) < 30
    assert position_spread_deg(gateway, tags) < 8
    assert position_spread_deg(corner, corner + np.array([[1.0, 0, 0], [-1.0, 0, 0]])) == 90.0
    # along a line seen end on: no spread at all
    assert position_spread_deg(np.zeros(3), np.outer(np.arange(1, 5), [0, 1.0, 0])) == 0.0

    def data(task, fixed, moving):
        n = len(moving)
        f = np.tile(fixed, (n, 1))
        return SimpleNamespace(train=np.arange(n), task=task,
                               positions=lambda idx: (moving[idx], f[idx], moving[idx]) if task == "rx"
                               else (f[idx], moving[idx], moving[idx]))

    walk_rx, walk_tx, tag_tx = data("rx", corner, room), data("tx", corner, room), data("tx", gateway, tags)
    assert spreads_wide(walk_rx) and spreads_wide(walk_tx) and not spreads_wide(tag_tx)
    c = CoherentGaussianConfig()
    assert [scan_planes(c, d) for d in (walk_rx, walk_tx, tag_tx)] == [0, 0, SCAN_PLANES]
    assert [uses_pursuit(c, d) for d in (walk_rx, walk_tx, tag_tx)] == [True, True, False]
    c = CoherentGaussianConfig(images=3, pursuit="on")
    assert scan_planes(c, walk_rx) == 3 and uses_pursuit(c, tag_tx)
    assert not uses_pursuit(CoherentGaussianConfig(pursuit="off"), walk_tx)
