"""Tests of the built-in rooms (rfmitsuba.scenes): they load in Sionna RT, have the sizes and
furniture of the issue, and match a fresh run of scripts/build_scenes.py byte for byte."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from rfmitsuba import scenes
from rfmitsuba.core.errors import SceneError
from rfmitsuba.sim import scene_builder as sb
from rfmitsuba.sim.geometry import RoomGeometry

ROOT = Path(__file__).resolve().parents[2]

# interior sizes of the built-in rooms (metres)
SIZES = {"bedroom": (4.4, 3.5, 2.8), "living_room": (4.3, 3.5, 2.8), "dining_room": (4.5, 3.8, 2.8),
         "large_room": (11.0, 7.5, 2.8)}
# furniture each built-in room holds (object ids in the scene)
FURNITURE = {"bedroom": {"bed", "wardrobe", "desk", "chair", "nightstand", "radiator"},
             "living_room": {"sofa", "coffee_table", "tv_stand", "tv", "bookshelf"},
             "dining_room": {"table", "chair_1", "chair_2", "chair_3", "chair_4", "sideboard", "fridge"},
             "large_room": {"sofa", "dining_table", "desk_1", "desk_2", "metal_cabinet", "bookshelf"}}
METAL = {"bedroom": "radiator", "living_room": "tv", "dining_room": "fridge", "large_room": "metal_cabinet"}


def test_available_and_path():
    assert scenes.available() == ["bedroom", "living_room", "dining_room", "large_room"]
    for n in scenes.available():
        assert scenes.path(n).is_file() and scenes.path(n).name == f"{n}.xml"
    with pytest.raises(SceneError, match="unknown scene 'attic'.*bedroom"):
        scenes.path("attic")
    with pytest.raises(SceneError, match="unknown scene 'attic'"):
        scenes.description("attic")


@pytest.mark.parametrize("name", list(SIZES))
def test_builtin_loads_in_sionna(variant, name):
    from rfmitsuba import plugins

    plugins.register()
    import sionna.rt as rt

    desc = scenes.description(name)
    scene = rt.load_scene(str(scenes.path(name)), merge_shapes=False)
    assert sorted(scene.objects) == sorted(sb.shape_ids(desc))
    mats = {m.id: m for m in desc.materials}
    for obj_name, obj in scene.objects.items():
        rm = obj.radio_material
        want = mats[rm.name]
        assert rm.itu_type == want.type, obj_name
        assert float(rm.thickness[0]) == pytest.approx(want.thickness, rel=1e-6)
    assert scene.get(METAL[name]).radio_material.itu_type == "metal"
    assert scene.get("window").radio_material.itu_type == "glass" if name != "large_room" else \
        scene.get("window_north").radio_material.itu_type == "glass"


@pytest.mark.parametrize("name", list(SIZES))
def test_builtin_sizes_structure_and_furniture(name):
    g = RoomGeometry.from_xml(scenes.path(name))
    np.testing.assert_allclose(g.lo, [0.0, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(g.hi, SIZES[name], atol=1e-6)
    kinds = {s.kind for s in g.shapes}
    assert {"wall", "floor", "ceiling", "door", "window", "furniture"} <= kinds
    assert FURNITURE[name] <= set(g.objects)
    desc = scenes.description(name)
    assert sb.triangle_count(desc) <= 1200       # small meshes: boxes only
    # composite pieces stay addressable by object id
    if name == "bedroom":
        assert {s.id for s in g.shapes if s.object == "bed"} == {"bed__furniture_wood", "bed__soft_textile"}
    # the room keeps a usable free floor for people (>= 25 % of the floor area at 0.25 m clearance)
    rng = np.random.default_rng(0)
    feet = np.c_[g.lo[:2] + g.size[:2] * rng.random((4000, 2)), np.zeros(4000)]
    assert g.free_mask(feet, clearance=0.25, body_height=1.7).mean() > 0.25


def _load_build_script():
    spec = importlib.util.spec_from_file_location("build_scenes", ROOT / "scripts" / "build_scenes.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_checked_in_scenes_match_build_script(tmp_path):
    build = _load_build_script()
    build.build(tmp_path, list(scenes.available()))
    for name in scenes.available():
        fresh = sorted(p.relative_to(tmp_path / name) for p in (tmp_path / name).rglob("*") if p.is_file())
        here = sorted(p.relative_to(ROOT / "scenes" / name) for p in (ROOT / "scenes" / name).rglob("*")
                      if p.is_file())
        assert fresh == here, f"{name}: files differ; run python scripts/build_scenes.py"
        for rel in fresh:
            assert (tmp_path / name / rel).read_bytes() == (ROOT / "scenes" / name / rel).read_bytes(), \
                f"{name}/{rel} differs from a fresh build; run python scripts/build_scenes.py"


def test_build_script_rejects_unknown_room(capsys):
    build = _load_build_script()
    assert build.main(["--out", "/nonexistent", "attic"]) == 2
    assert "unknown room(s) attic" in capsys.readouterr().err
