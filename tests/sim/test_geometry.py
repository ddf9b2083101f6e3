"""Tests of rfmitsuba.sim.geometry: reading scene XML, free space, placement errors, sampling, segments."""
from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from rfmitsuba import scenes
from rfmitsuba.core.errors import PlacementError, SceneError
from rfmitsuba.data.scene_xml import kind_of, object_of
from rfmitsuba.sim import scene_builder as sb
from rfmitsuba.sim.geometry import RoomGeometry


@pytest.fixture(scope="module")
def bedroom() -> RoomGeometry:
    return RoomGeometry.from_scene("bedroom")


def furniture_boxes(name: str) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Independent reference: world boxes (object id, lo, hi) straight from the room description."""
    out = []
    for f in scenes.description(name).furniture:
        for p in f.parts:
            lo, hi = sb._box_mesh(f, p).bounds
            out.append((f.id, lo, hi))
    return out


def box_distance(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Euclidean distance [N] from points to an axis-aligned box (0 inside)."""
    d = np.maximum(np.maximum(lo - points, points - hi), 0.0)
    return np.linalg.norm(d, axis=1)


# ---------------------------------------------------------------- reading

def write_xml(folder, body: str, *, mesh: bool = True):
    folder.mkdir(parents=True, exist_ok=True)
    if mesh:
        (folder / "meshes").mkdir(exist_ok=True)
        trimesh.creation.box(bounds=[[0, 0, 0], [1, 2, 3]]).export(folder / "meshes" / "b.ply")
    p = folder / "s.xml"
    p.write_text(f'<scene version="2.1.0">{body}</scene>')
    return p


def test_id_convention():
    assert kind_of("mesh-wall_south") == "wall" and kind_of("floor") == "floor"
    assert kind_of("window_east") == "window" and kind_of("bed__soft") == "furniture"
    assert object_of("mesh-bed__soft_textile") == "bed" and object_of("chair_1") == "chair_1"


def test_missing_file_and_malformed_xml(tmp_path):
    with pytest.raises(SceneError, match="nope.xml does not exist"):
        RoomGeometry.from_xml(tmp_path / "nope.xml")
    bad = tmp_path / "bad.xml"
    bad.write_text('<scene version="2.1.0"><shape type="ply" id="a"></scene>')
    with pytest.raises(SceneError, match=r"bad.xml: malformed XML"):
        RoomGeometry.from_xml(bad)


def test_missing_mesh_names_the_mesh(tmp_path):
    p = write_xml(tmp_path, '<shape type="ply" id="wall_x"><string name="filename" value="meshes/gone.ply"/>'
                            '</shape>', mesh=False)
    with pytest.raises(SceneError, match=r"shape 'wall_x': mesh file .*gone.ply does not exist"):
        RoomGeometry.from_xml(p)


def test_unreadable_mesh(tmp_path):
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "junk.ply").write_text("this is not a ply file\n")
    p = write_xml(tmp_path, '<shape type="ply" id="wall_x"><string name="filename" value="meshes/junk.ply"/>'
                            '</shape>', mesh=False)
    with pytest.raises(SceneError, match="junk.ply"):
        RoomGeometry.from_xml(p)


def test_unsupported_shape_type(tmp_path):
    p = write_xml(tmp_path, '<shape type="cube" id="box1"/>')
    with pytest.raises(SceneError, match=r"shape 'box1': shape type 'cube' is not supported"):
        RoomGeometry.from_xml(p)


def test_scene_without_walls(tmp_path):
    p = write_xml(tmp_path, '<shape type="ply" id="crate"><string name="filename" value="meshes/b.ply"/></shape>')
    with pytest.raises(SceneError, match="no floor shape"):
        RoomGeometry.from_xml(p)


def test_unknown_builtin_scene():
    with pytest.raises(SceneError, match="unknown scene 'attic'"):
        RoomGeometry.from_scene("attic")


def test_to_world_transforms_match_mitsuba(variant, tmp_path):
    """Our reading of to_world (translate, rotate, scale, matrix, defaults) agrees with Mitsuba's loader."""
    import mitsuba as mi

    body = """
      <default name="dx" value="0.5"/>
      <shape type="ply" id="a"><string name="filename" value="meshes/b.ply"/>
        <transform name="to_world"><scale value="0.5"/><rotate z="1" angle="30"/>
          <translate x="$dx" y="1" z="0.25"/></transform></shape>
      <shape type="ply" id="b"><string name="filename" value="meshes/b.ply"/>
        <transform name="to_world"><rotate value="1, 1, 0" angle="-45"/><scale x="2" y="1" z="0.5"/>
        </transform></shape>
      <shape type="ply" id="c"><string name="filename" value="meshes/b.ply"/>
        <transform name="to_world"><matrix value="0 -1 0 3  1 0 0 -1  0 0 1 0.5  0 0 0 1"/></transform></shape>
    """
    p = write_xml(tmp_path, body)
    from rfmitsuba.data.scene_xml import read_shapes

    ours = {s.id: s.mesh for s in read_shapes(p)}
    scene = mi.load_file(str(p))
    for shape in scene.shapes():
        bb = shape.bbox()
        lo, hi = ours[shape.id()].bounds
        np.testing.assert_allclose(lo, np.array(bb.min), atol=1e-5)
        np.testing.assert_allclose(hi, np.array(bb.max), atol=1e-5)


# ---------------------------------------------------------------- bounds and points

def test_bounds_and_kinds(bedroom):
    lo, hi = bedroom.bounds
    np.testing.assert_allclose(lo, [0, 0, 0], atol=1e-6)
    np.testing.assert_allclose(hi, [4.4, 3.5, 2.8], atol=1e-6)
    lo[0] = 99.0                                        # a copy: the geometry is unchanged
    assert bedroom.lo[0] == 0.0
    assert {"bed", "wardrobe", "desk", "chair", "nightstand", "radiator"} == set(bedroom.objects)


def test_check_points_messages(bedroom):
    bed_lo, bed_hi = bedroom.furniture_bounds()["bed"]
    inside_bed = 0.5 * (bed_lo + bed_hi)
    inside_bed[2] = 0.2
    good = np.array([1.5, 1.0, 1.2])
    with pytest.raises(PlacementError, match=r"antenna 1 at \(\d\.\d{3}, \d\.\d{3}, 0\.200\) is inside 'bed'"):
        bedroom.check_points(np.array([good, inside_bed]))
    with pytest.raises(PlacementError, match=r"antenna 2 at \(5\.000, 1\.000, 1\.000\) is outside the room"):
        bedroom.check_points(np.array([good, good, [5.0, 1.0, 1.0]]))
    with pytest.raises(PlacementError, match=r"person 0 at \(0\.500, nan, 1\.000\) is not finite"):
        bedroom.check_points(np.array([[0.5, np.nan, 1.0]]), what="person")
    with pytest.raises(PlacementError, match="not finite"):
        bedroom.check_points(np.array([[np.inf, 1.0, 1.0]]))
    with pytest.raises(PlacementError, match=r"is within 0.3 m of 'wardrobe'"):
        bedroom.check_points(np.array([[0.8, 1.5, 1.0]]), clearance=0.3)
    with pytest.raises(PlacementError, match="outside the room"):
        bedroom.check_points(np.array([[1.0, 1.0, 3.0]]))          # above the ceiling
    with pytest.raises(PlacementError, match=r"shape \[N, 3\]"):
        bedroom.check_points(np.zeros((4, 2)))
    bedroom.check_points(np.array([good]))                          # no error


def test_free_mask_agrees_with_box_reference(bedroom):
    rng = np.random.default_rng(1)
    pts = bedroom.lo + bedroom.size * rng.random((20000, 3))
    for clearance in (0.0, 0.1):
        got = bedroom.free_mask(pts, clearance=clearance)
        dist = np.min([box_distance(pts, lo, hi) for _, lo, hi in furniture_boxes("bedroom")], axis=0)
        room = np.min(np.minimum(pts - bedroom.lo, bedroom.hi - pts), axis=1)
        # our hulls grow boxes by the clearance on each face (corners included), so free => far enough,
        # and far enough (with the corner allowance sqrt(3) * clearance) => free
        assert np.all(dist[got] > clearance - 1e-9) and np.all(room[got] >= clearance)
        surely_free = (dist > math.sqrt(3) * clearance + 1e-9) & (room >= clearance) & (dist > 1e-9)
        assert np.all(got[surely_free])


def test_sample_free_never_inside_furniture(bedroom):
    pts = bedroom.sample_free(5000, rng=np.random.default_rng(3), z_range=(0.3, 2.2), clearance=0.1)
    assert pts.shape == (5000, 3) and pts.dtype == np.float64
    assert np.all(pts[:, 2] >= 0.3) and np.all(pts[:, 2] <= 2.2)
    assert np.all(pts >= bedroom.lo + 0.1) and np.all(pts <= bedroom.hi - 0.1)
    for obj, lo, hi in furniture_boxes("bedroom"):
        assert np.all(box_distance(pts, lo, hi) >= 0.1 - 1e-9), obj
    # seeded: same seed, same points
    again = bedroom.sample_free(5000, rng=np.random.default_rng(3), z_range=(0.3, 2.2), clearance=0.1)
    np.testing.assert_array_equal(pts, again)
    # uniform: furniture-free regions are hit in proportion to their volume (a quarter of x -> ~ a quarter)
    assert 0.1 < np.mean(pts[:, 0] < 1.1) < 0.4


def test_sample_free_gives_many_points_in_one_call():
    """10 000 free points in one call, every one inside the height range and clear of furniture (its
    speed is a benchmark's business, not a test's)."""
    g = RoomGeometry.from_scene("large_room")
    pts = g.sample_free(10000, rng=0, z_range=(0.5, 2.0), clearance=0.1)
    assert pts.shape == (10000, 3) and (pts[:, 2] >= 0.5).all() and (pts[:, 2] <= 2.0).all()
    assert g.free_mask(pts, clearance=0.1).all()


def test_sample_free_impossible_requests(bedroom):
    with pytest.raises(PlacementError, match="no free space"):
        bedroom.sample_free(10, rng=0, clearance=2.0)
    with pytest.raises(PlacementError, match="z_range"):
        bedroom.sample_free(10, rng=0, z_range=(2.0, 1.0))
    # a 1.3 m clearance leaves a small box above the bed, and the bed's own clearance fills it
    with pytest.raises(PlacementError, match="found only 0 of 10"):
        bedroom.sample_free(10, rng=0, clearance=1.3, max_tries=5)


# ---------------------------------------------------------------- segments

def test_segment_clear_cases(bedroom):
    bed_lo, bed_hi = bedroom.furniture_bounds()["bed"]
    y = 0.5 * (bed_lo[1] + bed_hi[1])
    assert not bedroom.segment_clear([1.5, y, 0.3], [4.3, y, 0.3])          # through the bed
    assert bedroom.segment_clear([1.5, y, 1.5], [4.3, y, 1.5])              # over it
    assert not bedroom.segment_clear([1.5, 1.0, 1.0], [5.0, 1.0, 1.0])      # through the east wall
    assert not bedroom.segment_clear([1.5, 1.0, 1.0], [1.5, 1.0, np.nan])
    # a standing body cannot pass over the bed, and not under the desk
    assert not bedroom.segment_clear([1.5, y, 0.0], [3.0, y, 0.0], body_height=1.7)
    desk_lo, desk_hi = bedroom.furniture_bounds()["desk"]
    mid = 0.5 * (desk_lo + desk_hi)
    assert bedroom.segment_clear([mid[0] - 0.4, mid[1], 0.3], [mid[0] + 0.4, mid[1], 0.3])   # between the legs
    assert not bedroom.segment_clear([mid[0], 2.0, 0.0], [mid[0], 3.3, 0.0], body_height=1.7)
    assert bedroom.segment_blocker([1.5, y, 0.3], [4.3, y, 0.3]) == "'bed'"
    assert bedroom.segment_blocker([1.5, 1.0, 1.0], [5.0, 1.0, 1.0]) == "the walls"


def test_segment_clear_agrees_with_dense_sampling(bedroom):
    """Parity with a plain reference: points every 2 mm along the segment tested by free_mask."""
    rng = np.random.default_rng(7)
    a = bedroom.lo + bedroom.size * rng.random((300, 3))
    b = bedroom.lo + bedroom.size * rng.random((300, 3))
    s = np.linspace(0.0, 1.0, 3000)[:, None]
    disagree = 0
    for p, q in zip(a, b):
        exact = bedroom.segment_clear(p, q)
        sampled = bool(np.all(bedroom.free_mask(p + s * (q - p))))
        if not sampled:
            assert not exact                 # a sampled hit is a hit
        disagree += exact != sampled
    assert disagree <= 3                     # only grazing hits shorter than the sample spacing


# ---------------------------------------------------------------- devices and plots

@pytest.mark.parametrize("name", ["bedroom", "living_room", "dining_room", "large_room"])
def test_corner_is_free_and_in_a_corner(name):
    g = RoomGeometry.from_scene(name)
    c = g.corner(inset=0.3, height=2.0)
    assert c.shape == (3,) and c[2] == pytest.approx(g.lo[2] + 2.0)
    assert g.free_mask(c[None], clearance=0.05)[0]
    near_x = min(c[0] - g.lo[0], g.hi[0] - c[0])
    near_y = min(c[1] - g.lo[1], g.hi[1] - c[1])
    assert near_x == pytest.approx(0.3) and near_y == pytest.approx(0.3)


def test_corner_fails_clearly_when_blocked(bedroom):
    with pytest.raises(PlacementError, match="no free corner"):
        bedroom.corner(height=5.0)


def test_plot_top_view(bedroom, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    bedroom.plot_top_view(ax)
    labels = {t.get_text() for t in ax.texts}
    assert set(bedroom.objects) <= labels
    assert len(ax.patches) >= len(bedroom.objects) + 4
    fig.savefig(tmp_path / "top.png")
    plt.close(fig)
    assert (tmp_path / "top.png").stat().st_size > 1000
