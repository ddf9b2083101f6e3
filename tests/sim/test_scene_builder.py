"""Tests of rfmitsuba.sim.scene_builder: descriptions -> Mitsuba XML + PLY, validation, TOML round trip."""
from __future__ import annotations

import dataclasses
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import trimesh
from rfmitsuba.scenes import catalog

from rfmitsuba.core import config
from rfmitsuba.core.errors import SceneError
from rfmitsuba.sim import scene_builder as sb


def small_room(**kw) -> sb.RoomDescription:
    base = dict(
        name="tiny", size=(3.0, 2.5, 2.5), wall_thickness=0.2,
        materials=[sb.Material("wall_brick", "brick", 0.2), sb.Material("slab", "concrete", 0.2),
                   sb.Material("door_wood", "wood", 0.04), sb.Material("pane", "glass", 0.01),
                   sb.Material("oak", "wood", 0.02), sb.Material("soft", "carpet_tile", 0.05),
                   sb.Material("tissue", "body-tissue", 0.2)],
        wall_material="wall_brick", floor_material="slab", ceiling_material="slab",
        openings=[sb.Opening("door", "south", offset=0.2, width=0.9, height=2.0, material="door_wood"),
                  sb.Opening("window", "east", offset=0.8, width=1.0, height=1.0, sill=1.0, material="pane",
                             panel_thickness=0.01)],
        furniture=[sb.bed("bed", "oak", "soft", origin=(1.2, 0.3), size=(1.4, 2.0)),
                   sb.chair("chair", "oak", origin=(0.3, 1.5)),
                   sb.block("statue", "tissue", origin=(0.3, 0.9), size=(0.3, 0.3, 1.5))],
    )
    base.update(kw)
    return sb.RoomDescription(**base)


def test_itu_types_match_installed_sionna(variant):
    from sionna.rt.radio_materials.itu import ITU_MATERIALS_PROPERTIES

    assert set(sb.ITU_TYPES) == set(ITU_MATERIALS_PROPERTIES)


def test_write_scene_files_and_xml(tmp_path):
    desc = small_room()
    xml = sb.write_scene(desc, tmp_path)
    assert xml == tmp_path / "tiny.xml"
    root = ET.parse(xml).getroot()
    assert root.tag == "scene" and root.attrib["version"] == "2.1.0"
    bsdfs = {b.attrib["id"]: b for b in root.findall("bsdf")}
    assert bsdfs["wall_brick"].attrib["type"] == "itu-radio-material"
    assert bsdfs["wall_brick"].find("string[@name='type']").attrib["value"] == "brick"
    assert float(bsdfs["pane"].find("float[@name='thickness']").attrib["value"]) == 0.01
    assert bsdfs["tissue"].attrib["type"] == "body-tissue"
    shapes = [s.attrib["id"] for s in root.findall("shape")]
    assert shapes == sb.shape_ids(desc)
    # the bed has two materials -> one shape per material, named <id>__<material>
    assert "bed__oak" in shapes and "bed__soft" in shapes and "chair" in shapes
    for s in root.findall("shape"):
        assert s.attrib["type"] == "ply"
        fn = s.find("string[@name='filename']").attrib["value"]
        mesh = trimesh.load(tmp_path / fn, force="mesh")
        assert len(mesh.faces) > 0 and len(mesh.faces) % 12 == 0      # boxes only
        assert s.find("ref").attrib["id"] in bsdfs
    # ids are one namespace in Sionna: no shape is named like a material
    assert not set(shapes) & set(bsdfs)


def test_openings_are_real_holes_with_a_panel(tmp_path):
    desc = small_room()
    meshes = {sid: m for sid, _, m in sb.room_meshes(desc)}
    t = desc.wall_thickness
    door = desc.openings[0]
    # centre of the door opening, in the middle of the south wall's thickness
    centre = np.array([door.offset + door.width / 2, -t / 2, door.height / 2])
    for comp in meshes["wall_south"].split(only_watertight=False):
        lo, hi = comp.bounds
        assert not np.all((centre > lo) & (centre < hi)), "wall box covers the door opening"
    lo, hi = meshes["door"].bounds
    # panel inside the opening, separated by the gap, thinner than the wall: no coplanar faces
    np.testing.assert_allclose(lo[[0, 2]], [door.offset + door.gap, door.gap], atol=1e-9)
    np.testing.assert_allclose(hi[[0, 2]], [door.offset + door.width - door.gap, door.height - door.gap], atol=1e-9)
    assert hi[1] - lo[1] == pytest.approx(door.panel_thickness)
    assert lo[1] > -t and hi[1] < 0.0
    # the window on the east wall: wall boxes above and below it, none across it
    win = desc.openings[1]
    c = np.array([desc.size[0] + t / 2, win.offset + win.width / 2, win.sill + win.height / 2])
    comps = meshes["wall_east"].split(only_watertight=False)
    assert len(comps) == 4                              # before, below, above, after
    for comp in comps:
        lo, hi = comp.bounds
        assert not np.all((c > lo) & (c < hi))
    # every wall is closed boxes
    assert all(m.is_watertight for m in comps)


def test_furniture_helpers_are_composite():
    chair = sb.chair("c", "oak", origin=(0.0, 0.0))
    assert len(chair.parts) == 6                      # seat, back, four legs
    b = sb.bed("b", "oak", "soft", origin=(0.0, 0.0))
    assert {p.name for p in b.parts} == {"frame", "headboard", "mattress"}
    t = sb.table("t", "oak", origin=(0.0, 0.0), size=(1.0, 0.5, 0.7))
    assert len(t.parts) == 5
    # yaw 180 about the origin mirrors the footprint into negative x, y
    lo, hi = sb._furniture_mesh(sb.chair("c", "oak", origin=(2.0, 2.0), yaw_deg=180.0)).bounds
    np.testing.assert_allclose(lo[:2], [1.55, 1.55], atol=1e-9)
    np.testing.assert_allclose(hi[:2], [2.0, 2.0], atol=1e-9)


@pytest.mark.parametrize("change, message", [
    (dict(materials=[sb.Material("wall_brick", "adamantium", 0.2)]), "unknown type 'adamantium'"),
    (dict(wall_material="nope"), "uses material 'nope'"),
    (dict(size=(3.0, float("nan"), 2.5)), "size y"),
    (dict(size=(3.0, -1.0, 2.5)), "size y"),
    (dict(name="bad name"), "room name"),
])
def test_invalid_descriptions(change, message):
    with pytest.raises(SceneError, match=message):
        sb.validate(small_room(**change))


def test_invalid_openings_and_furniture():
    d = small_room()
    d.openings.append(sb.Opening("door_2", "south", offset=0.5, width=0.9, height=2.0, material="door_wood"))
    with pytest.raises(SceneError, match="overlap in the south wall"):
        sb.validate(d)
    d = small_room()
    d.openings[0].width = 5.0
    with pytest.raises(SceneError, match="does not fit in the south wall"):
        sb.validate(d)
    d = small_room()
    d.openings[1].panel_thickness = 0.3
    with pytest.raises(SceneError, match="panel_thickness"):
        sb.validate(d)
    d = small_room()
    d.openings[0].id = "hatch"
    with pytest.raises(SceneError, match="start with 'door' or 'window'"):
        sb.validate(d)
    d = small_room()
    d.furniture.append(sb.block("crate", "oak", origin=(2.8, 2.0), size=(0.5, 0.5, 0.5)))
    with pytest.raises(SceneError, match="furniture crate spans"):
        sb.validate(d)
    d = small_room()
    d.furniture.append(sb.block("crate", "oak", origin=(1.3, 0.5), size=(0.5, 0.5, 0.5)))
    with pytest.raises(SceneError, match="furniture bed and crate overlap"):
        sb.validate(d)
    d = small_room()
    d.furniture.append(sb.block("wall_unit", "oak", origin=(0.3, 2.0), size=(0.5, 0.2, 0.5)))
    with pytest.raises(SceneError, match="must not start with wall"):
        sb.validate(d)


def test_material_and_shape_ids_must_differ():
    d = small_room()
    d.materials.append(sb.Material("chair", "wood", 0.02))
    with pytest.raises(SceneError, match="name both a shape and a material"):
        sb.validate(d)
    d = small_room()
    d.materials.append(sb.Material("concrete", "concrete", 0.2))
    with pytest.raises(SceneError, match="ITU type name"):
        sb.validate(d)


def test_bad_description_writes_nothing(tmp_path):
    d = small_room(wall_material="nope")
    with pytest.raises(SceneError):
        sb.write_scene(d, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_no_silent_overwrite(tmp_path):
    sb.write_scene(small_room(), tmp_path)
    with pytest.raises(SceneError, match="exists"):
        sb.write_scene(small_room(), tmp_path)
    sb.write_scene(small_room(), tmp_path, overwrite=True)
    assert sb.write_scene(small_room(), tmp_path, name="other").name == "other.xml"


@pytest.mark.parametrize("name", list(catalog.ROOMS))
def test_description_round_trips_through_toml(name, tmp_path):
    desc = catalog.ROOMS[name]()
    back = config.from_toml(sb.RoomDescription, config.to_toml(desc))
    assert back == desc
    assert sb.scene_xml(back) == sb.scene_xml(desc)
    config.save(desc, tmp_path / "room.toml")
    assert config.load(sb.RoomDescription, tmp_path / "room.toml") == desc


def test_toml_is_editable_by_hand():
    text = config.to_toml(small_room())
    edited = text.replace("size = [\n    3.0,", "size = [\n    3.5,")
    desc = config.from_toml(sb.RoomDescription, edited)
    assert desc.size[0] == 3.5
    lo, hi = {sid: m for sid, _, m in sb.room_meshes(desc)}["floor"].bounds   # the floor grows too
    assert hi[0] == pytest.approx(3.5 + desc.wall_thickness)


def test_writing_is_deterministic(tmp_path):
    a = sb.write_scene(small_room(), tmp_path / "a")
    b = sb.write_scene(small_room(), tmp_path / "b")
    assert a.read_bytes() == b.read_bytes()
    for f in sorted((tmp_path / "a" / "meshes").iterdir()):
        assert f.read_bytes() == (tmp_path / "b" / "meshes" / f.name).read_bytes()


def test_written_room_loads_in_sionna(variant, tmp_path):
    from rfmitsuba import plugins

    plugins.register()
    import sionna.rt as rt

    desc = small_room()
    scene = rt.load_scene(str(sb.write_scene(desc, tmp_path)), merge_shapes=False)
    assert sorted(scene.objects) == sorted(sb.shape_ids(desc))
    assert type(scene.get("statue").radio_material).__name__ == "BodyTissueMaterial"
    assert scene.get("wall_east").radio_material.itu_type == "brick"


def test_dataclass_fields_are_typed():
    # every description field has a concrete type config can check (no Any)
    for cls in (sb.RoomDescription, sb.Material, sb.Box, sb.Furniture, sb.Opening):
        for f in dataclasses.fields(cls):
            assert f.type not in ("Any", "typing.Any")
