"""rfmitsuba.sim.visibility: reflection points by the image method (closed forms) and ray-cast
existence / blockage of specular paths in hand-made rooms (a box, a pillar, a finite plate)."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from rfmitsuba.core.errors import ConfigError
from rfmitsuba.rf.images import Plane, image_maps

#: a 4 x 3 x 2.5 m room: x in [0, 4], y in [0, 3], z in [0, 2.5]
ROOM = trimesh.creation.box(extents=(4.0, 3.0, 2.5), transform=trimesh.transformations.translation_matrix((2, 1.5, 1.25)))


def _planes(*pl, order=1):
    """Image maps of the given planes (no furniture), every plane sequence its own image."""
    return image_maps(list(pl), [], room_order=order, furniture_order=0, distinct_paths=True)


def _vis(*extra):
    from rfmitsuba.sim.visibility import SpecularVisibility

    return SpecularVisibility([ROOM, *extra])


def test_reflection_points_closed_form():
    """Floor reflection of y = (1, 1, 1) to x = (3, 1, 2): the image (1, 1, -1); the path meets
    z = 0 a third of the way, at (5/3, 1, 0). A corner (x = 0 then y = 0): the points lie on their
    planes and the path's legs make the image's length."""
    from rfmitsuba.sim.visibility import reflection_points

    x, y = np.array([[3.0, 1.0, 2.0]]), np.array([[1.0, 1.0, 1.0]])
    m = _planes(Plane((0.0, 0.0, 1.0), 0.0, "floor"))
    p, ok = reflection_points(x, y, m.planes, m.order)
    assert ok.all() and np.isnan(p[0, 0]).all()                         # the direct path has none
    np.testing.assert_allclose(p[0, 1, 0], [5 / 3, 1.0, 0.0], atol=1e-12)
    m = _planes(Plane((1.0, 0.0, 0.0), 0.0, "x0"), Plane((0.0, 1.0, 0.0), 0.0, "y0"), order=2)
    i = m.label.index("x0|y0")
    p, ok = reflection_points(x, y, m.planes, m.order)
    assert ok[0, i]
    assert abs(p[0, i, 0, 0]) < 1e-12 and abs(p[0, i, 1, 1]) < 1e-12
    legs = np.linalg.norm(p[0, i, 0] - y[0]) + np.linalg.norm(p[0, i, 1] - p[0, i, 0]) + np.linalg.norm(x[0] - p[0, i, 1])
    assert legs == pytest.approx(np.linalg.norm(x[0] - m.apply(y[0])[i]), abs=1e-12)


def test_reflection_needs_both_ends_on_one_side():
    """A plane between the two devices reflects nothing: the image is not valid."""
    from rfmitsuba.sim.visibility import reflection_points

    m = _planes(Plane((1.0, 0.0, 0.0), 2.0, "x2"))
    _, ok = reflection_points(np.array([[3.0, 1, 1]]), np.array([[1.0, 1, 1]]), m.planes, m.order)
    assert ok[0, 0] and not ok[0, 1]


def test_box_room_walls_exist_and_a_pillar_blocks_the_direct_path():
    """Every first-order wall path exists in an empty box room and is clear; a pillar between the
    devices blocks the direct path (which still exists) but not the ceiling's path over it; a
    plane outside the room (x = 5) has no face, so its path does not exist."""
    walls = [Plane((1.0, 0.0, 0.0), 0.0, "x0"), Plane((1.0, 0.0, 0.0), 4.0, "x4"), Plane((0.0, 0.0, 1.0), 0.0, "z0"),
             Plane((0.0, 0.0, 1.0), 2.5, "z2.5"), Plane((1.0, 0.0, 0.0), 5.0, "x5")]
    m = _planes(*walls)
    x, y = np.array([[3.0, 1.5, 1.0]]), np.array([[1.0, 1.5, 1.0]])
    ex, cl = _vis()(x, y, m.planes, m.order)
    lab = dict(zip(m.label, range(len(m))))
    assert ex[0, [lab["direct"], lab["x0"], lab["x4"], lab["z0"], lab["z2.5"]]].all()
    assert cl[0, [lab["direct"], lab["x0"], lab["x4"], lab["z0"], lab["z2.5"]]].all()
    assert not ex[0, lab["x5"]] and not cl[0, lab["x5"]]
    pillar = trimesh.creation.box(extents=(0.2, 0.2, 1.6), transform=trimesh.transformations.translation_matrix((2, 1.5, 0.8)))
    ex, cl = _vis(pillar)(x, y, m.planes, m.order)
    assert ex[0, lab["direct"]] and not cl[0, lab["direct"]]
    assert not cl[0, lab["z0"]]                                           # the floor bounce passes through it
    assert cl[0, lab["z2.5"]]                                             # over the pillar's top


def test_finite_plate_reflects_only_where_it_is():
    """A 1 x 1 m plate at z = 1.5 over x in [1.5, 2.5]: a path whose reflection point falls on it
    exists; moved so that the point falls beside it, the path does not."""
    plate = trimesh.Trimesh(vertices=[[1.5, 1.0, 1.5], [2.5, 1.0, 1.5], [2.5, 2.0, 1.5], [1.5, 2.0, 1.5]],
                            faces=[[0, 1, 2], [0, 2, 3]])
    m = _planes(Plane((0.0, 0.0, 1.0), 1.5, "plate"))
    x = np.array([[3.0, 1.5, 0.5], [3.8, 1.5, 0.5]])
    y = np.array([[1.0, 1.5, 0.5], [3.0, 1.5, 0.5]])                     # points at x = 2.0 and x = 3.4
    ex, cl = _vis(plate)(x, y, m.planes, m.order)
    assert ex[0, 1] and cl[0, 1]
    assert not ex[1, 1]


def test_flush_surface_counts_as_the_planes_face():
    """A panel 2 cm in front of the wall x = 0 reflects as the wall: the wall's path exists
    (within ``flush``), and is not counted as blocked by the panel."""
    panel = trimesh.creation.box(extents=(0.02, 3.0, 2.5), transform=trimesh.transformations.translation_matrix((0.03, 1.5, 1.25)))
    m = _planes(Plane((1.0, 0.0, 0.0), 0.0, "x0"))
    x, y = np.array([[3.0, 1.0, 1.0]]), np.array([[1.0, 2.0, 1.2]])
    ex, cl = _vis(panel)(x, y, m.planes, m.order)
    assert ex[0, 1] and cl[0, 1]
    from rfmitsuba.sim.visibility import SpecularVisibility

    ex, cl = SpecularVisibility([ROOM, panel], flush=0.01)(x, y, m.planes, m.order)
    assert ex[0, 1] and not cl[0, 1]                                      # a tighter band: the panel blocks


def test_bad_input_is_named():
    from rfmitsuba.sim.visibility import SpecularVisibility, reflection_points

    m = _planes(Plane((0.0, 0.0, 1.0), 0.0, "floor"))
    with pytest.raises(ConfigError, match="finite"):
        _vis()(np.array([[np.nan, 0, 0]]), np.zeros((1, 3)), m.planes, m.order)
    with pytest.raises(ConfigError, match="planes"):
        reflection_points(np.zeros((1, 3)), np.zeros((1, 3)), m.planes[:, :, :3], m.order)
    with pytest.raises(ConfigError, match="orders"):
        reflection_points(np.zeros((1, 3)), np.zeros((1, 3)), m.planes, m.order + 5)
    with pytest.raises(ConfigError, match="at least one mesh"):
        SpecularVisibility([])
    with pytest.raises(ConfigError, match="tol"):
        SpecularVisibility([ROOM], tol=0.1, probe=0.05)


def test_a_leg_leaving_a_flush_panel_still_sees_what_stands_further_on():
    """A panel flush with the wall x = 0 is looked past on the leg that leaves the wall, so a
    pillar further along that leg still blocks the path."""
    panel = trimesh.creation.box(extents=(0.02, 3.0, 2.5), transform=trimesh.transformations.translation_matrix((0.03, 1.5, 1.25)))
    pillar = trimesh.creation.box(extents=(0.2, 0.2, 2.5), transform=trimesh.transformations.translation_matrix((1.0, 1.17, 1.25)))
    m = _planes(Plane((1.0, 0.0, 0.0), 0.0, "x0"))
    x, y = np.array([[2.0, 0.5, 1.0]]), np.array([[1.0, 2.5, 1.2]])     # reflects at x = 0, y = 1.83; leaves past (1, 1)
    ex, cl = _vis(panel)(x, y, m.planes, m.order)
    assert ex[0, 1] and cl[0, 1]
    ex, cl = _vis(panel, pillar)(x, y, m.planes, m.order)
    assert ex[0, 1] and not cl[0, 1]


def test_incidence_cosine_closed_form():
    """Floor bounce between (1, 1.5, 1) and (3, 1.5, 1): the path meets the floor at 45 degrees
    (cos = 1/sqrt 2); the direct path reports 1."""
    m = _planes(Plane((0.0, 0.0, 1.0), 0.0, "floor"))
    tr = _vis().trace(np.array([[3.0, 1.5, 1.0]]), np.array([[1.0, 1.5, 1.0]]), m.planes, m.order)
    assert tr.exists.all() and tr.clear.all()
    np.testing.assert_allclose(tr.cos_incidence[0], [1.0, 2 ** -0.5], atol=1e-9)


def test_crossings_count_the_surfaces_of_each_material_group():
    """Between (0.5, 1.5, 1) and (3.5, 1.5, 1) stand a wooden box and two panes of glass (two thin
    boxes, each crossed twice): the direct path crosses 2 wood and 4 glass surfaces; its floor
    bounce passes under them (clear, no crossings). ``max_crossings`` caps the count per leg; a
    group per mesh is the default; groups must match the meshes."""
    from rfmitsuba.sim.visibility import SpecularVisibility

    def box(ext, at):
        return trimesh.creation.box(extents=ext, transform=trimesh.transformations.translation_matrix(at))

    wood = box((0.4, 0.4, 0.4), (1.5, 1.5, 1.0))
    glass = [box((0.02, 0.6, 0.6), (2.5, 1.5, 1.0)), box((0.02, 0.6, 0.6), (3.0, 1.5, 1.0))]
    m = _planes(Plane((0.0, 0.0, 1.0), 0.0, "floor"))
    x, y = np.array([[3.5, 1.5, 1.0]]), np.array([[0.5, 1.5, 1.0]])
    vis = SpecularVisibility([ROOM, wood, *glass], groups=["concrete", "wood", "glass", "glass"])
    assert vis.group_names == ["concrete", "wood", "glass"]
    tr = vis.trace(x, y, m.planes, m.order)
    assert tr.exists.all() and not tr.clear[0, 0] and tr.clear[0, 1]
    np.testing.assert_array_equal(tr.crossings[0], [[0, 2, 4], [0, 0, 0]])
    capped = SpecularVisibility([ROOM, wood, *glass], groups=["c", "w", "g", "g"], max_crossings=3)
    np.testing.assert_array_equal(capped.trace(x, y, m.planes, m.order).crossings[0, 0], [0, 2, 1])
    assert _vis(wood).trace(x, y, m.planes, m.order).crossings.shape == (1, 2, 2)   # one group per mesh
    with pytest.raises(ConfigError, match="one group per mesh"):
        SpecularVisibility([ROOM, wood], groups=["concrete"])


def test_shortest_segment_and_the_tracers_threshold():
    """Between (0.5, 1.5, 1) and (3.5, 1.5, 1) stand a 6 mm and a 20 mm pane: the direct path's
    shortest segment is the thin pane's 6 mm (closed form), and a tracer that drops segments of
    1 cm or less (Sionna RT) has no direct path there; the floor bounce passes under both
    (shortest segment: its legs, 1.80 m). With only the 20 mm pane the direct path stays. A path
    that does not exist has an infinite shortest segment."""
    def pane(t, at_x):
        return trimesh.creation.box(extents=(t, 0.6, 0.6), transform=trimesh.transformations.translation_matrix((at_x, 1.5, 1.0)))

    m = _planes(Plane((0.0, 0.0, 1.0), 0.0, "floor"))
    x, y = np.array([[3.5, 1.5, 1.0]]), np.array([[0.5, 1.5, 1.0]])
    tr = _vis(pane(0.006, 1.5), pane(0.02, 2.5)).trace(x, y, m.planes, m.order)
    np.testing.assert_allclose(tr.shortest_segment[0], [0.006, np.hypot(1.5, 1.0)], atol=2e-4)
    kept = tr.without_short_segments(0.01)
    assert not kept.exists[0, 0] and not kept.clear[0, 0] and kept.exists[0, 1] and kept.clear[0, 1]
    assert np.all(kept.crossings[0, 0] == 0) and np.isinf(kept.shortest_segment[0, 0])
    assert tr.without_short_segments(None) is tr
    thick = _vis(pane(0.02, 2.5)).trace(x, y, m.planes, m.order)
    np.testing.assert_allclose(thick.shortest_segment[0, 0], 0.02, atol=2e-4)
    assert thick.without_short_segments(0.01).exists[0, 0]
    below = _vis().trace(np.array([[3.5, 1.5, -1.0]]), y, m.planes, m.order)   # receiver under the floor
    assert not below.exists[0, 1] and np.isinf(below.shortest_segment[0, 1])
