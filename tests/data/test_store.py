"""Tests of rfmitsuba.data.store: format, splits, atomic chunks, damaged folders, generation and resume."""
import hashlib
import json
import shutil

import numpy as np
import pytest

from rfmitsuba.core.errors import DatasetError, PlacementError
from rfmitsuba.data import split as splits
from rfmitsuba.data import store as D
from rfmitsuba.sim import generate as gen


def tiny(path, S=3, A=10, seed=0, **kw):
    rng = np.random.default_rng(seed)
    hp = np.full((S, 3), np.nan)
    hp[1:] = rng.random((S - 1, 3))
    pas = rng.random((S, A, 90, 360)).astype(np.float32)
    ds = D.write_dataset(path, pas=pas, antenna_pos=rng.random((A, 3)), person_pos=hp, **kw)
    return ds, pas, hp


def digests(root):
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*.npy"))}


# ---------------------------------------------------------------- format and API

def test_write_then_open_round_trip(tmp_path):
    ds, pas, hp = tiny(tmp_path / "d", meta={"task": "tx", "frequency_hz": 5e9, "fixed_pos": [1, 2, 3]})
    ds = D.open_dataset(tmp_path / "d")
    assert (ds.task, ds.frequency_hz, ds.num_antennas, ds.num_states) == ("tx", 5e9, 10, 3)
    assert np.array_equal(ds.pas(1), pas[1]) and ds.pas(1).dtype == np.float32
    assert ds.channel(0).shape == (10, 16) and ds.channel(0).dtype == np.complex64
    assert np.isnan(ds.person_pos[0]).all() and np.allclose(ds.person_pos[1:], hp[1:])
    assert np.allclose(ds.fixed_pos, [1, 2, 3])
    meta = json.loads((tmp_path / "d" / "meta.json").read_text())
    assert meta["format"] == D.FORMAT and meta["num_states"] == 3 and len(meta["array"]["element_positions_m"]) == 16


def test_arrays_flat_view_row_order(tmp_path):
    ds, pas, hp = tiny(tmp_path / "d", S=3, A=4)
    arr = ds.arrays()
    assert arr["pas"].shape == (12, 90, 360)
    k = 2 * 4 + 3  # state 2, antenna 3
    assert np.array_equal(arr["pas"][k], pas[2, 3])
    assert np.array_equal(arr["antenna_pos"][k], ds.antenna_pos[3])
    assert np.allclose(arr["person_pos"][k], hp[2]) and np.isnan(arr["person_pos"][:4]).all()
    sub = ds.arrays([2])
    assert sub["pas"].shape == (4, 90, 360) and np.array_equal(sub["state"], [2] * 4)


def test_split_fractions_disjoint_and_saved(tmp_path):
    sp = splits.make_split(900, 35, seed=3)
    assert len(sp.antenna_test) == 180 and len(sp.person_test) == 7  # 20 % and ~19 %
    assert not set(sp.antenna_test) & set(sp.antenna_train)
    assert sorted([*sp.antenna_test, *sp.antenna_train]) == list(range(900))
    assert np.array_equal(splits.make_split(900, 35, seed=3).antenna_test, sp.antenna_test)
    assert not np.array_equal(splits.make_split(900, 35, seed=4).antenna_test, sp.antenna_test)
    ds, _, _ = tiny(tmp_path / "d", S=6, A=20, seed=0)
    again = D.open_dataset(tmp_path / "d").split
    assert np.array_equal(again.antenna_test, ds.split.antenna_test) and len(again.antenna_test) == 4


def test_write_dataset_bad_inputs(tmp_path):
    hp = np.full((2, 3), np.nan)
    hp[1] = 1
    with pytest.raises(DatasetError, match=r"\[S, A, 90, 360\]"):
        D.write_dataset(tmp_path / "a", pas=np.zeros((2, 3, 90, 180)), antenna_pos=np.zeros((3, 3)), person_pos=hp)
    with pytest.raises(DatasetError, match="antenna_pos"):
        D.write_dataset(tmp_path / "b", pas=np.zeros((2, 3, 90, 360)), antenna_pos=np.full((3, 3), np.nan),
                        person_pos=hp)
    with pytest.raises(DatasetError, match="row 0 must be NaN"):
        D.write_dataset(tmp_path / "c", pas=np.zeros((2, 3, 90, 360)), antenna_pos=np.zeros((3, 3)),
                        person_pos=np.ones((2, 3)))
    with pytest.raises(DatasetError, match="task"):
        D.write_dataset(tmp_path / "e", pas=np.zeros((2, 3, 90, 360)), antenna_pos=np.zeros((3, 3)),
                        person_pos=hp, meta={"task": "sideways"})


def test_not_a_dataset_and_foreign_folder(tmp_path):
    with pytest.raises(DatasetError, match="no meta.json"):
        D.open_dataset(tmp_path)
    (tmp_path / "keep.txt").write_text("mine")
    with pytest.raises(DatasetError, match="not empty"):
        tiny(tmp_path)
    assert (tmp_path / "keep.txt").read_text() == "mine"


def test_other_configuration_refused_nothing_overwritten(tmp_path):
    tiny(tmp_path / "d", meta={"task": "rx"})
    before = digests(tmp_path / "d")
    meta_before = (tmp_path / "d" / "meta.json").read_text()
    with pytest.raises(DatasetError, match="task is 'rx' there and 'tx' in this call"):
        tiny(tmp_path / "d", meta={"task": "tx"})
    assert digests(tmp_path / "d") == before and (tmp_path / "d" / "meta.json").read_text() == meta_before


def test_scene_location_is_not_configuration(tmp_path):
    """The same scene (name and hashes) from another checkout resumes the folder; another scene
    content is refused by its hash."""
    scene = {"name": "bedroom", "file": "/a/scenes/bedroom.xml", "sha256": "x1", "meshes_sha256": "m1"}
    A = 10
    sp = splits.make_split(A, 2)
    ap = np.random.default_rng(0).random((A, 3))
    D.prepare_folder(tmp_path / "d", {"scene": scene}, antenna_pos=ap, split=sp)
    D.prepare_folder(tmp_path / "d", {"scene": {**scene, "file": "/b/other/checkout/bedroom.xml"}}, antenna_pos=ap,
                     split=sp)
    with pytest.raises(DatasetError, match="scene.sha256 is 'x1' there and 'x2' in this call"):
        D.prepare_folder(tmp_path / "d", {"scene": {**scene, "sha256": "x2"}}, antenna_pos=ap, split=sp)


def test_truncated_chunk_named_on_open(tmp_path):
    tiny(tmp_path / "d")
    f = tmp_path / "d" / "chunks" / "00002" / "pas.npy"
    f.write_bytes(f.read_bytes()[:1000])
    with pytest.raises(DatasetError, match="00002.*truncated"):
        D.open_dataset(tmp_path / "d")


def test_missing_chunk_named_on_open(tmp_path):
    tiny(tmp_path / "d")
    shutil.rmtree(tmp_path / "d" / "chunks" / "00001")
    with pytest.raises(DatasetError, match="00001 is missing"):
        D.open_dataset(tmp_path / "d")


def test_corrupt_chunk_found_by_verify(tmp_path):
    tiny(tmp_path / "d")
    f = tmp_path / "d" / "chunks" / "00001" / "pas.npy"
    b = bytearray(f.read_bytes())
    b[-5] ^= 0xFF  # same size, one flipped byte
    f.write_bytes(bytes(b))
    ds = D.open_dataset(tmp_path / "d")  # header and size are fine
    assert ds.verify() == [1]
    with pytest.raises(DatasetError, match="00001.*sha256"):
        D.check_chunk(tmp_path / "d", 1, 10, full=True)


def test_state_out_of_range(tmp_path):
    ds, _, _ = tiny(tmp_path / "d")
    with pytest.raises(DatasetError, match="state 3"):
        ds.pas(3)


def test_first_difference_names_the_nested_key_and_both_values():
    assert D.first_difference({"a": {"b": 1, "c": [1, 2]}}, {"a": {"b": 1, "c": [1, 3]}}) == ("a.c[1]", 2, 3)
    assert D.first_difference({"a": 1}, {"a": 1}) is None
    assert D.first_difference({"a": 1}, {"b": 1}) == ("a", 1, "<missing>")


# ---------------------------------------------------------------- generation (Sionna)

def test_quick_dataset_contents(quick_dataset):
    ds = quick_dataset
    from rfmitsuba.sim import person as person
    from rfmitsuba.sim.geometry import RoomGeometry

    assert ds.num_antennas == gen.QUICK["positions"] and ds.num_states == 1 + gen.QUICK["person_positions"]
    assert ds.meta["scene"]["name"] == "bedroom" and len(ds.meta["scene"]["sha256"]) == 64
    for key in ("solver", "seeds", "versions", "units", "array", "person"):
        assert key in ds.meta
    g = RoomGeometry.from_xml(ds.meta["scene"]["file"])
    g.check_points(ds.antenna_pos.astype(np.float64))  # never inside furniture
    hp = ds.person_pos[1:]
    d = np.linalg.norm(ds.antenna_pos[:, None, :2] - hp[None, :, :2], axis=-1)
    below = ds.antenna_pos[:, None, 2] < person.HEIGHT + 0.1
    assert not np.any((d < person.radius()) & below)  # never inside the person
    p0 = np.asarray(ds.pas(0))
    assert np.isfinite(p0).all() and p0.max() > 0
    # the person changes some PAS, not all
    diff = np.abs(np.asarray(ds.pas(1)) - p0).max(axis=(1, 2)) / p0.max(axis=(1, 2))
    assert diff.max() > 0.01 and ds.verify() == []


def test_generate_kill_and_resume_is_bit_identical(quick_dataset, tmp_path):
    cfg = gen.quick_config("bedroom", task="rx", seed=0)
    out = tmp_path / "resumed"
    gen.generate(out, cfg, quiet=True, stop_after=2)  # "killed" after two states
    assert sorted(p.name for p in (out / "chunks").iterdir()) == ["00000", "00001"]
    # a half-written chunk (never renamed) is cleaned up and redone
    (out / "chunks" / ".tmp-00002-999").mkdir()
    (out / "chunks" / ".tmp-00002-999" / "pas.npy").write_bytes(b"junk")
    ds = gen.generate(out, cfg, quiet=True)
    assert digests(out) == digests(quick_dataset.path)
    assert not list((out / "chunks").glob(".tmp-*")) and ds.num_states == 5
    # damaged chunk: generate refuses, --repair redoes it identically
    f = out / "chunks" / "00003" / "pas.npy"
    f.write_bytes(f.read_bytes()[:500])
    with pytest.raises(DatasetError, match="00003.*--repair"):
        gen.generate(out, cfg, quiet=True)
    gen.generate(out, cfg, quiet=True, repair=True)
    assert digests(out) == digests(quick_dataset.path)


def test_generate_refuses_other_configuration(quick_dataset, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(quick_dataset.path, out)
    before = digests(out)
    with pytest.raises(DatasetError, match="generate.material"):
        gen.generate(out, gen.quick_config("bedroom", task="rx", seed=0, material="metal"), quiet=True)
    with pytest.raises(DatasetError, match="task is 'rx' there and 'tx' in this call"):
        gen.generate(out, gen.quick_config("bedroom", task="tx", seed=0), quiet=True)
    assert digests(out) == before


def test_place_antennas_rejects_impossible_requests(variant):
    from rfmitsuba import scenes
    from rfmitsuba.sim.geometry import RoomGeometry

    g = RoomGeometry.from_xml(scenes.path("bedroom"))
    with pytest.raises(PlacementError):
        gen.place_antennas(g, 5, rng=np.random.default_rng(0), z_range=(0.5, 2.0), clearance=5.0,
                         walk_positions=np.zeros((0, 3)), body_radius=0.3, body_height=1.8)
    with pytest.raises(PlacementError, match="not finite|outside"):
        g.check_points(np.array([[np.nan, 1, 1]]), what="antenna")


def test_fingerprint_follows_the_content_not_the_location(tmp_path):
    tiny(tmp_path / "d")
    fp = D.open_dataset(tmp_path / "d").fingerprint()
    assert fp == D.open_dataset(tmp_path / "d").fingerprint() and len(fp) == 64
    shutil.copytree(tmp_path / "d", tmp_path / "moved")
    assert D.open_dataset(tmp_path / "moved").fingerprint() == fp  # where it lies is not what it holds
    ds = D.open_dataset(tmp_path / "moved")
    pas = np.array(ds.pas(2))
    pas[0, 0, 0] += 1.0
    D.write_chunk(tmp_path / "moved", 2, pas=pas)  # one value of one state changed
    assert D.open_dataset(tmp_path / "moved").fingerprint() != fp
    _, pas, hp = tiny(tmp_path / "again")
    ap = D.open_dataset(tmp_path / "again").antenna_pos
    D.write_dataset(tmp_path / "other_split", pas=pas, antenna_pos=ap, person_pos=hp, seed=5)  # same arrays
    assert not np.array_equal(D.open_dataset(tmp_path / "other_split").split.antenna_test, ds.split.antenna_test)
    assert D.open_dataset(tmp_path / "other_split").fingerprint() != fp
    (tmp_path / "d" / "chunks" / "00001" / "chunk.json").unlink()
    with pytest.raises(DatasetError, match="00001: chunk.json"):
        D.open_dataset(tmp_path / "d", check=False).fingerprint()
