"""Tests of rfmitsuba.sim.person: body mesh, seeded walks that stay clear, walk checks, Sionna object."""
from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from rfmitsuba import scenes
from rfmitsuba.core.errors import PlacementError
from rfmitsuba.sim import person
from rfmitsuba.sim.geometry import RoomGeometry


@pytest.fixture(scope="module")
def bedroom() -> RoomGeometry:
    return RoomGeometry.from_scene("bedroom")


def test_mesh_size_and_shape():
    m = person.person_mesh([1.0, 2.0, 0.0], 0.0)
    lo, hi = m.bounds
    assert hi[2] - lo[2] == pytest.approx(1.7) and lo[2] == pytest.approx(0.0)
    assert hi[1] - lo[1] == pytest.approx(0.45, abs=0.01)        # shoulders along y at heading 0
    np.testing.assert_allclose(0.5 * (lo + hi)[:2], [1.0, 2.0], atol=1e-9)   # feet under the bbox centre
    parts = m.split(only_watertight=False)
    assert len(parts) == 7 and all(p.is_watertight for p in parts)        # legs, torso, arms, neck, head
    assert m.volume < 0.5 * np.prod(hi - lo)                              # not one box
    turned = person.person_mesh([0, 0, 0], math.pi / 2)
    assert turned.extents[0] == pytest.approx(0.45, abs=0.01)
    with pytest.raises(PlacementError, match="finite"):
        person.person_mesh([np.nan, 0, 0], 0.0)


@pytest.mark.parametrize("name", ["bedroom", "dining_room", "large_room"])
def test_walk_is_seeded_and_clear(name):
    g = RoomGeometry.from_scene(name)
    pos, head, t = person.walk(g, n=35, duration_s=60.0, seed=3)
    assert pos.shape == (35, 3) and pos.dtype == np.float64 and head.shape == (35,)
    assert np.all(pos[:, 2] == g.floor_z)
    np.testing.assert_array_equal(pos, person.walk(g, seed=3).positions)
    assert not np.array_equal(pos, person.walk(g, seed=4).positions)
    assert np.all(g.free_mask(pos, clearance=0.25, body_height=1.7))
    for a, b in zip(pos[:-1], pos[1:]):
        assert g.segment_clear(a, b, clearance=0.25, body_height=1.7)
    speed = np.linalg.norm(np.diff(pos, axis=0), axis=1) / np.diff(t)
    assert np.all(speed <= 1.0 + 1e-9) and np.median(speed) >= 0.5
    person.check_walk(g, pos, clearance=0.25)


def test_check_walk_rejects_walls_furniture_and_nan(bedroom):
    ok = person.walk(bedroom, seed=0).positions
    through_wall = ok.copy()
    through_wall[5] = [5.0, 1.0, 0.0]
    with pytest.raises(PlacementError, match="person 5 at .* is outside the room"):
        person.check_walk(bedroom, through_wall)
    bed_lo, bed_hi = bedroom.furniture_bounds()["bed"]
    y = 0.5 * (bed_lo[1] + bed_hi[1])
    across_bed = np.array([[1.5, y, 0.0], [bed_hi[0] + 0.5, y, 0.0]])
    across_bed[1, 0] = min(across_bed[1, 0], bedroom.hi[0] - 0.01)
    with pytest.raises(PlacementError):
        person.check_walk(bedroom, across_bed)
    nan = ok.copy()
    nan[2, 1] = np.nan
    with pytest.raises(PlacementError, match="person 2 .* not finite"):
        person.check_walk(bedroom, nan)


def test_perturber_materials_and_snippet():
    assert set(person.PERTURBER_MATERIALS) == {"tissue", "metal", "concrete"}
    assert person.PERTURBER_MATERIALS["tissue"][0] == "body-tissue"
    assert 'type="body-tissue"' in person.xml_snippet()
    with pytest.raises(PlacementError, match="unknown perturber kind 'wood'"):
        person.xml_snippet(kind="wood")


def test_scene_object_moves_in_sionna(variant, tmp_path):
    from rfmitsuba import plugins, scenes

    plugins.register()
    import sionna.rt as rt

    scene = rt.load_scene(str(scenes.path("bedroom")), merge_shapes=False)
    obj = person.scene_object(tmp_path, kind="tissue")
    scene.edit(add=obj)
    assert type(scene.get("person").radio_material).__name__ == "BodyTissueMaterial"
    person.place(obj, [2.0, 1.9, 0.0], 0.7)
    bb = obj.mi_mesh.bbox()
    np.testing.assert_allclose(0.5 * (np.array(bb.min) + np.array(bb.max))[:2], [2.0, 1.9], atol=1e-4)
    assert float(bb.min[2]) == pytest.approx(0.0, abs=1e-4) and float(bb.max[2]) == pytest.approx(1.7, abs=1e-4)
    metal = person.radio_material("metal", name="statue_metal")
    assert metal.itu_type == "metal"


def test_heading_turns_the_shoulders():
    a = person.person_mesh((0, 0, 0), 0.0).bounds
    b = person.person_mesh((0, 0, 0), math.pi / 2).bounds
    ext_a, ext_b = a[1] - a[0], b[1] - b[0]
    np.testing.assert_allclose(ext_a[[1, 0]], ext_b[[0, 1]], atol=1e-6)   # x and y extents swap


@pytest.mark.parametrize("name", scenes.available())
def test_short_walk_samples_the_full_walk(name):
    """Four positions of a 60 s walk are instants of the 35-step walk of the same seed."""
    g = RoomGeometry.from_scene(name)
    full = person.walk(g, n=35, seed=0)
    short = person.walk(g, n=4, seed=0)
    idx = [int(np.argmin(np.abs(full.times - t))) for t in short.times]
    np.testing.assert_allclose(short.positions, full.positions[idx])
    assert np.all(g.free_mask(short.positions, clearance=0.25, body_height=person.HEIGHT))


def test_bad_walk_arguments(bedroom):
    with pytest.raises(PlacementError, match="n >= 1"):
        person.walk(bedroom, n=0)
    with pytest.raises(PlacementError, match="no clear walk"):
        person.walk(bedroom, clearance=1.6, max_attempts=2)


def test_written_ply_is_the_body(tmp_path):
    path = person.write_person_ply(tmp_path / "h.ply")
    m = trimesh.load(path, force="mesh")
    assert m.bounds[1][2] - m.bounds[0][2] == pytest.approx(person.HEIGHT, abs=0.02)


def test_a_walk_that_avoids_another_keeps_its_distance_at_every_moment(bedroom):
    first = person.walk(bedroom, n=60, seed=0).positions
    w = person.walk(bedroom, n=60, seed=5, avoid=first[None], gap_m=0.62)
    assert np.hypot(*(w.positions[:, :2] - first[:, :2]).T).min() >= 0.62
    person.check_walk(bedroom, w.positions)
    plain = person.walk(bedroom, n=60, seed=5)
    assert np.hypot(*(plain.positions[:, :2] - first[:, :2]).T).min() < 0.62   # the draw alone would collide
    np.testing.assert_array_equal(plain.positions, person.walk(bedroom, n=60, seed=5, avoid=None).positions)
