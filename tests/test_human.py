"""Tests of rfmitsuba.human: the body mesh, seeded walks and their checks."""
import math

import numpy as np
import pytest
import trimesh

from rfmitsuba import human, scenes
from rfmitsuba.errors import PlacementError
from rfmitsuba.geometry import RoomGeometry


@pytest.fixture(scope="module")
def bedroom() -> RoomGeometry:
    return RoomGeometry.from_scene("bedroom")


def test_body_size_and_parts():
    m = human.human_mesh((1.0, 2.0, 0.0), 0.0)
    lo, hi = m.bounds
    assert hi[2] - lo[2] == pytest.approx(human.HEIGHT, abs=0.02)
    assert lo[2] == pytest.approx(0.0, abs=1e-6)                      # feet on the floor
    width = max(hi[0] - lo[0], hi[1] - lo[1])
    assert width == pytest.approx(human.WIDTH, abs=0.03)
    parts = m.split(only_watertight=False)
    assert len(parts) >= 6                                            # legs, torso, arms, neck, head
    # the bounding-box centre is above the feet whatever the heading (what place() relies on)
    for h in np.linspace(-math.pi, math.pi, 7):
        c = human.human_mesh((1.0, 2.0, 0.0), h).bounds.mean(axis=0)
        np.testing.assert_allclose(c[:2], [1.0, 2.0], atol=1e-6)


def test_heading_turns_the_shoulders():
    a = human.human_mesh((0, 0, 0), 0.0).bounds
    b = human.human_mesh((0, 0, 0), math.pi / 2).bounds
    ext_a, ext_b = a[1] - a[0], b[1] - b[0]
    np.testing.assert_allclose(ext_a[[1, 0]], ext_b[[0, 1]], atol=1e-6)   # x and y extents swap


def test_walk_is_seeded_and_clear(bedroom):
    w1 = human.walk(bedroom, seed=3)
    w2 = human.walk(bedroom, seed=3)
    np.testing.assert_array_equal(w1.positions, w2.positions)
    assert w1.positions.shape == (35, 3) and w1.times[-1] == pytest.approx(60.0)
    assert not np.array_equal(w1.positions, human.walk(bedroom, seed=4).positions)
    human.check_walk(bedroom, w1.positions, clearance=0.25)            # raises if not clear
    steps = np.linalg.norm(np.diff(w1.positions[:, :2], axis=0), axis=1)
    dt = np.diff(w1.times)
    assert np.all(steps / dt <= 1.0 + 1e-9)                            # never faster than 1 m/s


@pytest.mark.parametrize("name", scenes.available())
def test_short_walk_samples_the_full_walk(name):
    """Four positions of a 60 s walk are instants of the 35-step walk of the same seed."""
    g = RoomGeometry.from_scene(name)
    full = human.walk(g, n=35, seed=0)
    short = human.walk(g, n=4, seed=0)
    idx = [int(np.argmin(np.abs(full.times - t))) for t in short.times]
    np.testing.assert_allclose(short.positions, full.positions[idx])
    assert np.all(g.free_mask(short.positions, clearance=0.25, body_height=human.HEIGHT))


def test_walk_through_a_wall_is_rejected(bedroom):
    lo, hi = bedroom.lo, bedroom.hi
    inside = np.array([lo[0] + 1.0, lo[1] + 1.0, lo[2]])
    outside = np.array([hi[0] + 1.0, lo[1] + 1.0, lo[2]])
    with pytest.raises(PlacementError, match="human 1"):
        human.check_walk(bedroom, [inside, outside])


def test_walk_with_nan_is_rejected(bedroom):
    p = human.walk(bedroom, n=5, seed=0).positions.copy()
    p[2, 0] = np.nan
    with pytest.raises(PlacementError, match="not finite"):
        human.check_walk(bedroom, p)


def test_bad_walk_arguments(bedroom):
    with pytest.raises(PlacementError, match="n >= 1"):
        human.walk(bedroom, n=0)
    with pytest.raises(PlacementError, match="no clear walk"):
        human.walk(bedroom, clearance=1.6, max_attempts=2)


def test_perturber_materials():
    assert set(human.PERTURBER_MATERIALS) == {"tissue", "metal", "concrete"}
    with pytest.raises(ValueError, match="wood"):
        human.radio_material("wood")


def test_written_ply_is_the_body(tmp_path):
    path = human.write_human_ply(tmp_path / "h.ply")
    m = trimesh.load(path, force="mesh")
    assert m.bounds[1][2] - m.bounds[0][2] == pytest.approx(human.HEIGHT, abs=0.02)
