"""Image maps (rfmitsuba.rf.images): counts, closed-form reflected paths, and agreement with Sionna RT."""
from __future__ import annotations

import numpy as np
import pytest

from rfmitsuba.core.errors import ConfigError
from rfmitsuba.rf import images

LO, HI = np.zeros(3), np.array([4.0, 3.0, 2.6])


def box_maps(order: int) -> images.ImageMaps:
    return images.image_maps(images.box_planes(LO, HI), room_order=order, furniture_order=0)


def test_box_image_counts():
    # order n adds the distinct lattice images: 1, 6, 18 (30 sequences, 12 perpendicular pairs coincide), 38
    assert [len(box_maps(n)) for n in range(4)] == [1, 7, 25, 63]
    m = box_maps(3)
    assert m.label[0] == "direct" and m.order[0] == 0
    assert np.bincount(m.order).tolist() == [1, 6, 18, 38]


def test_maps_are_isometries():
    m = box_maps(3)
    for A in m.A:
        np.testing.assert_allclose(A @ A.T, np.eye(3), atol=1e-12)
    # an odd number of reflections turns the frame over
    np.testing.assert_allclose(np.linalg.det(m.A), (-1.0) ** m.order, atol=1e-12)


def test_first_order_path_length_is_the_reflected_path():
    """|x - M(y)| equals the length of y -> reflection point on the wall -> x (closed form)."""
    m = box_maps(1)
    y, x = np.array([0.7, 2.2, 1.9]), np.array([3.1, 0.8, 1.2])
    for i in range(1, 7):
        n = m.A[i] @ np.ones(3) - np.ones(3)          # -2 along the plane's axis
        axis = int(np.flatnonzero(n)[0])
        wall = m.b[i][axis] / 2.0                     # plane offset d (b = 2 d n)
        # reflection point: on the segment from x to the image, where it crosses the plane
        img = m.apply(y)[i]
        s = (wall - x[axis]) / (img[axis] - x[axis])
        r = x + s * (img - x)
        assert np.isclose(r[axis], wall) and 0 < s < 1
        assert np.linalg.norm(y - r) + np.linalg.norm(r - x) == pytest.approx(np.linalg.norm(img - x), rel=1e-12)


def test_arrays_round_trip_and_bad_shapes():
    m = box_maps(2)
    back = images.ImageMaps.from_arrays(m.to_arrays())
    np.testing.assert_array_equal(back.A, m.A)
    np.testing.assert_array_equal(back.b, m.b)
    assert back.label == m.label
    bad = m.to_arrays()
    bad["b"] = bad["b"][:-1]
    with pytest.raises(ConfigError, match="inconsistent"):
        images.ImageMaps.from_arrays(bad)
    with pytest.raises(ConfigError):
        images.image_maps(images.box_planes(LO, HI), room_order=-1)


def test_scene_maps_of_the_bedroom_have_furniture_and_no_duplicates():
    from rfmitsuba.sim.geometry import RoomGeometry

    geo = RoomGeometry.from_scene("bedroom")
    m = images.scene_image_maps(geo, room_order=2, furniture_order=2)
    assert len(m) > 25
    assert any(":" in lab for lab in m.label)  # furniture planes are named object:axis=value
    key = np.round(np.concatenate([m.A.reshape(len(m), -1), m.b], 1), 9)
    assert len(np.unique(key, axis=0)) == len(m)
    # the bed's faces flush against the east wall (x = 4.39 vs 4.40) make no image
    assert not any(lab.startswith("bed:x=4.39") for lab in m.label)


def test_every_sionna_path_in_a_box_comes_from_an_image(box_room, variant):
    """In a closed box, every specular path Sionna RT finds (depth <= 3) arrives from the direction
    of an image of the transmitter, and every first-order image is found."""
    from rfmitsuba.sim.simulate import Simulator, SolverConfig

    y = np.array([3.6, 2.6, 2.0])
    xs = np.array([[1.0, 1.0, 1.2], [2.5, 0.7, 0.9], [0.6, 2.2, 1.6]])
    sim = Simulator(box_room, fixed_pos=y, solver=SolverConfig(samples_per_src=50_000, refraction=False, threads=1))
    sim.set_positions(xs)
    ps = sim.solve()
    m = box_maps(3)
    for j, x in enumerate(xs):
        d = m.apply(y) - x
        u_img = d / np.linalg.norm(d, axis=1, keepdims=True)
        u_paths = ps.u_moving[j, :ps.num_paths[j]]
        cos = u_paths @ u_img.T                       # [P, S]
        err = np.degrees(np.arccos(np.clip(cos.max(axis=1), -1, 1)))
        assert err.max() < 0.2, f"a Sionna path at position {j} matches no image ({err.max():.2f} deg)"
        first = np.flatnonzero(m.order <= 1)
        found = np.degrees(np.arccos(np.clip(cos[:, first].max(axis=0), -1, 1)))
        assert found.max() < 0.2, f"a first-order image has no Sionna path at position {j}"


def test_distinct_paths_keep_both_orders_of_perpendicular_planes():
    """With ``distinct_paths`` every plane sequence is its own image (30 ordered pairs at order 2),
    and each image lists its planes in the order the path meets them."""
    m = images.image_maps(images.box_planes(LO, HI), room_order=2, furniture_order=0, distinct_paths=True)
    assert np.bincount(m.order).tolist() == [1, 6, 30]
    assert m.planes.shape == (37, 2, 4) and np.isnan(m.planes[0]).all() and np.isnan(m.planes[1, 1]).all()
    i = m.label.index("x=0.00|z=2.60")
    np.testing.assert_allclose(m.planes[i], [[1, 0, 0, 0.0], [0, 0, 1, 2.6]])
    # the composed map is the second plane's mirror after the first's
    (A1, b1), (A2, b2) = (images.Plane(tuple(p[:3]), p[3], "").matrix() for p in m.planes[i])
    np.testing.assert_allclose(m.A[i], A2 @ A1)
    np.testing.assert_allclose(m.b[i], A2 @ b1 + b2)
    back = images.ImageMaps.from_arrays(m.to_arrays())
    np.testing.assert_array_equal(back.planes, m.planes)


def test_face_planes_of_a_box_and_a_bed():
    """A box gives its six faces; a bed-like mesh (a frame box and a lower mattress box) also
    gives the mattress top, and planes smaller than ``min_area`` are left out."""
    import trimesh

    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5), transform=trimesh.transformations.translation_matrix((1, 0.5, 0.25)))
    got = {p.name: p for p in images.face_planes(box.vertices, box.faces, min_area=0.1)}
    assert set(got) == {"x=0.00", "x=2.00", "y=0.00", "y=1.00", "z=0.00", "z=0.50"}
    assert got["z=0.50"].normal == (0.0, 0.0, 1.0) and got["z=0.00"].normal == (0.0, 0.0, -1.0)
    mat = trimesh.creation.box(extents=(1.8, 0.8, 0.1), transform=trimesh.transformations.translation_matrix((1, 0.5, 0.35)))
    both = trimesh.util.concatenate([box, mat])
    names = [p.name for p in images.face_planes(both.vertices, both.faces, min_area=0.6)]
    assert "z=0.40" in names and "y=0.00" in names and "x=0.00" not in names   # x faces: 0.5 m^2
    with pytest.raises(ConfigError, match="furniture_planes"):
        images.scene_image_maps(None, furniture_planes="hull")
