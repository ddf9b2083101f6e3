"""Tests of rfmitsuba.data.one_walk: the One Walk layout, write -> read round trip, folders as the
One Walk loader reads them, stated and default options, bad folders, and a fuzzed reader
(hypothesis): whatever the files hold, reading succeeds with well-shaped arrays or raises
DatasetError naming the folder."""
import json
import shutil

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rfmitsuba.core.errors import DatasetError
from rfmitsuba.data import nerf2
from rfmitsuba.data import one_walk as ow
from rfmitsuba.data import store as D
from rfmitsuba.rf.bartlett_ref import normalize

Q8 = 0.5 / 255 + 1e-6   # 8-bit quantisation of a min-max normalised image


# --------------------------------------------------------------------------- round trip
@pytest.fixture(scope="module")
def exported(synthetic_ds, tmp_path_factory):
    """The synthetic dynamic dataset (30 antennas x (1 + 6) states) written in the One Walk layout."""
    src = D.open_dataset(synthetic_ds)
    out = ow.write(src, tmp_path_factory.mktemp("one_walk") / "ow")
    return src, out


@pytest.mark.parametrize("where", ["", "dynamic", "static"])
def test_round_trip_positions_splits_and_pas(exported, where):
    src, out = exported
    back = D.open_dataset(out / where if where else out)
    assert isinstance(back, ow.OneWalkDataset)
    S = 1 if where == "static" else src.num_states
    assert back.num_antennas == src.num_antennas and back.num_states == S
    assert back.task == src.task == "rx" and back.frequency_hz == src.frequency_hz and not back.measured
    assert np.allclose(back.antenna_pos, src.antenna_pos, atol=1e-6)
    assert np.allclose(back.fixed_pos, src.fixed_pos) and np.allclose(back.rx_to_world, np.eye(3))
    assert np.array_equal(back.split.antenna_train, src.split.antenna_train)
    assert np.array_equal(back.split.antenna_test, src.split.antenna_test)
    for s in range(S):
        p = np.asarray(back.pas(s))
        assert p.shape == (src.num_antennas, 90, 360) and p.dtype == np.float32
        assert np.abs(p - normalize(src.pas(s))).max() <= Q8
    assert np.array_equal(back.pas(0)[[3, 1]], np.asarray(back.pas(0))[[3, 1]])
    if S > 1:
        assert np.allclose(back.person_pos[1:], src.person_pos[1:], atol=1e-6) and np.isnan(back.person_pos[0]).all()
        assert np.array_equal(back.split.person_train, src.split.person_train)
        assert np.array_equal(back.split.person_test, src.split.person_test)
        assert np.array_equal(back.frame_idx, np.arange(S - 1))


def test_exported_folders_train_and_sample_like_the_source(exported):
    from rfmitsuba.data.samples import SampleData
    from rfmitsuba.data.views import TrainData

    src, out = exported
    t = TrainData.open(out)
    assert t.task == "rx" and np.allclose(t.transmitter, src.fixed_pos)
    assert np.array_equal(t.train, src.split.antenna_train) and np.array_equal(t.test, src.split.antenna_test)
    a, b = SampleData.open_samples(src.path, states="all"), SampleData.open_samples(out / "dynamic", states="all")
    assert np.array_equal(a.train, b.train) and np.array_equal(a.test, b.test)
    assert np.abs(b.pas(b.test) - a.pas(a.test)).max() <= Q8 + 1e-6
    assert np.allclose(a.person_pos[a.test], b.person_pos[b.test], atol=1e-6, equal_nan=True)


def test_the_layout_is_what_the_one_walk_loader_reads(exported):
    """Image names = index-file entries + '.png', 1-based; spectrum_info.csv row n is image n; the
    dynamic split is train x train (train), test x test (test), the rest (val)."""
    from PIL import Image

    src, out = exported
    A, H = src.num_antennas, src.num_states - 1
    st, dy = out / "static", out / "dynamic"
    names = sorted(p.stem for p in (st / "spectrum").glob("*.png"))
    assert names == [f"{i:05d}" for i in range(1, A + 1)]
    im = Image.open(st / "spectrum" / "00001.png")
    assert im.mode == "L" and im.size == (360, 90)
    assert (st / "rx_info.csv").read_text().splitlines()[0] == "x,y,z"
    assert "gateway1:" in (st / "gateway_info.yml").read_text()
    tr = (st / "train_index.txt").read_text().split()
    assert tr == [f"{i + 1:05d}" for i in src.split.antenna_train] and all((st / "spectrum" / f"{n}.png").is_file() for n in tr)
    lines = (dy / "spectrum_info.csv").read_text().splitlines()
    assert lines[0] == "index,rx_x,rx_y,rx_z,man_x,man_y,man_z,qx,qy,qz,qw,frame_idx" and len(lines) == 1 + H * A
    rows = [ln.split(",") for ln in lines[1:]]
    assert [int(r[0]) for r in rows] == list(range(1, H * A + 1))     # row n - 1 is image n
    split = {k: (dy / f"{k}_index.txt").read_text().split() for k in ("train", "val", "test")}
    assert sorted(sum(split.values(), [])) == [f"{n:05d}" for n in range(1, H * A + 1)]
    sp = src.split
    for k, want in (("train", lambda a, h: a in sp.antenna_train and h in sp.person_train),
                    ("test", lambda a, h: a in sp.antenna_test and h in sp.person_test)):
        for name in split[k]:
            r = rows[int(name) - 1]
            assert want((int(name) - 1) % A, int(r[11])) and (dy / "spectrums" / f"{name}.png").is_file()
    q = np.array([[float(c) for c in r[7:11]] for r in rows])
    assert np.allclose(np.linalg.norm(q, axis=1), 1)


def test_stage1_dataset_writes_a_static_folder_only(variant, tmp_path):
    from stage1_data import make_dataset

    src = D.open_dataset(make_dataset(tmp_path / "ds", num_antennas=12))
    out = ow.write(src, tmp_path / "ow")
    assert (out / "static").is_dir() and not (out / "dynamic").exists()
    back = D.open_dataset(out)
    assert back.num_states == 1 and np.allclose(back.antenna_pos, src.antenna_pos, atol=1e-6)
    assert np.abs(np.asarray(back.pas(0)) - normalize(src.pas(0))).max() <= Q8
    with pytest.raises(DatasetError, match="not empty"):
        ow.write(src, out)


# --------------------------------------------------------------------------- a small hand-made pair
A, H = 4, 3


def _pair(root, *, seed=0):
    """A static + dynamic pair of A positions and H frames, random 8-bit images, written by :func:`ow.write`."""
    rng = np.random.default_rng(seed)
    hp = np.full((1 + H, 3), np.nan)
    hp[1:] = rng.random((H, 3)) * 3
    pas = rng.random((1 + H, A, 90, 360)).astype(np.float32)
    from rfmitsuba.data.split import Split

    sp = Split(antenna_train=np.array([0, 1, 2]), antenna_test=np.array([3]), person_train=np.array([0, 1]),
               person_test=np.array([2]))
    src = D.write_dataset(root / "src", pas=pas, antenna_pos=rng.random((A, 3)) * 4, person_pos=hp, split=sp,
                          meta={"task": "rx", "fixed_pos": [0.5, 0.5, 2.0],
                                "person": {"headings_rad": [0.0, 1.0, 2.0]}})
    return src, ow.write(src, root / "ow")


@pytest.fixture
def pair(tmp_path):
    return _pair(tmp_path)


def _published(out):
    """Remove what only rfmitsuba writes: the folders as the One Walk code publishes them."""
    for f in out.rglob(nerf2.EXTRA):
        f.unlink()


def test_folder_as_published_takes_the_documented_defaults(pair):
    src, out = pair
    _published(out)
    back = ow.read(out / "dynamic")
    assert back.measured and back.task == "rx" and back.readout == "amplitude"
    assert back.frequency_hz == ow.DEFAULT_FREQUENCY_HZ and np.allclose(back.rx_to_world, np.eye(3))
    assert np.allclose(back.fixed_pos, [0.5, 0.5, 2.0])   # gateway_info.yml
    assert np.allclose(back.meta["person"]["headings_rad"], [0.0, 1.0, 2.0], atol=1e-6)
    cfg = ow.OneWalkConfig(frequency_hz=5e9, array_orientation=(0, 0, np.sin(np.pi / 4), np.cos(np.pi / 4)),
                           fixed_pos=(1, 2, 3))
    back = ow.read(out, config=cfg)
    assert back.frequency_hz == 5e9 and np.allclose(back.rx_to_world @ [1, 0, 0], [0, 1, 0])
    assert np.allclose(back.fixed_pos, [1, 2, 3])


def test_one_walk_names_and_rx_pos_csv_are_read(pair, tmp_path):
    src, out = pair
    _published(out)
    data = tmp_path / "data"
    shutil.copytree(out / "static", data / "static_dataset")
    shutil.copytree(out / "dynamic", data / "dynamic_dataset")
    (data / "static_dataset" / "rx_info.csv").rename(data / "static_dataset" / "rx_pos.csv")
    assert ow.layout(data) == "pair" and ow.layout(data / "dynamic_dataset") == "dynamic"
    for p in (data, data / "dynamic_dataset"):
        back = D.open_dataset(p)
        assert back.num_states == 1 + H and back.static_path == data / "static_dataset"
    assert D.open_dataset(data / "static_dataset").num_states == 1


def test_a_stated_static_folder(pair, tmp_path):
    src, out = pair
    dyn = tmp_path / "elsewhere" / "walk"
    shutil.copytree(out / "dynamic", dyn)
    with pytest.raises(DatasetError, match="the static folder .* does not exist"):
        ow.read(dyn)                                   # its rfmitsuba.json names ../static
    (dyn / nerf2.EXTRA).unlink()
    with pytest.raises(DatasetError, match="no static folder .*beside it"):
        ow.read(dyn)
    back = ow.read(dyn, config=ow.OneWalkConfig(static=str(out / "static")))
    assert back.num_states == 1 + H
    (dyn / nerf2.EXTRA).write_text(json.dumps({"static": "../../ow/static"}))
    assert ow.read(dyn).num_states == 1 + H


def test_without_frame_idx_or_orientation_frames_are_the_poses(pair):
    src, out = pair
    f = out / "dynamic" / "spectrum_info.csv"
    rows = [ln.split(",") for ln in f.read_text().splitlines()]
    f.write_text("\n".join(",".join(r[:7]) for r in rows) + "\n")
    back = ow.read(out)
    assert back.num_states == 1 + H and np.allclose(back.person_pos[1:], src.person_pos[1:], atol=1e-6)
    assert np.allclose(back.person_orientation[1:], [0, 0, 0, 1])
    assert np.array_equal(back.split.person_test, [2])


def test_frames_follow_frame_idx_not_row_order(pair):
    src, out = pair
    f = out / "dynamic" / "spectrum_info.csv"
    head, *rows = f.read_text().splitlines()
    rows = [r.split(",") for r in rows]
    for r in rows:
        r[11] = str(10 * (2 - int(r[11])))            # frames 20, 10, 0: the last person first
    f.write_text("\n".join([head] + [",".join(r) for r in reversed(rows)]) + "\n")
    back = ow.read(out)
    assert np.array_equal(back.frame_idx, [0, 10, 20])
    assert np.allclose(back.person_pos[1:], src.person_pos[1:][::-1], atol=1e-6)
    assert np.abs(np.asarray(back.pas(1)) - normalize(src.pas(3))).max() <= Q8
    assert np.array_equal(back.split.person_test, [0])


def test_index_files_that_disagree_with_the_static_split_warn(pair):
    src, out = pair
    d = out / "dynamic"
    tr = d / "train_index.txt"
    te = d / "test_index.txt"
    te.write_text(te.read_text() + "00009\n")         # frame 2 at position 0 (a static training position)
    (d / "val_index.txt").write_text("".join(ln + "\n" for ln in (d / "val_index.txt").read_text().split()
                                             if ln != "00009"))
    with pytest.warns(UserWarning, match="static folder's split of the positions is kept"):
        back = ow.read(out)
    assert np.array_equal(back.split.antenna_test, [3]) and back.warnings
    tr.write_text(tr.read_text() + te.read_text().split()[0] + "\n")
    with pytest.raises(DatasetError, match="in both train_index.txt and test_index.txt"):
        ow.read(out)


def test_quaternions():
    rng = np.random.default_rng(1)
    for q in rng.normal(size=(20, 4)):
        q = q / np.linalg.norm(q)
        back = ow.matrix_quaternion(nerf2.quaternion_matrix(q))
        assert np.allclose(back, q if q[3] >= 0 else -q, atol=1e-9)
    h = np.array([0.0, 0.5, -3.0])
    assert np.allclose(ow.quaternion_heading(ow.heading_quaternion(h)), h)


def _edit(path, old, new):
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


@pytest.mark.parametrize("change, message", [
    (lambda o: (o / "dynamic/spectrum_info.csv").write_text("index,rx_x,rx_y,rx_z,man_x,man_y\n1,0,0,0,0,0\n"),
     "no column 'man_z'"),
    (lambda o: _edit(o / "dynamic/spectrum_info.csv", "\n2,", "\n2,nan"), "not a finite number"),
    (lambda o: _edit(o / "dynamic/spectrum_info.csv", "\n2,", "\n1,"), "index 1 appears 2 times"),
    (lambda o: (o / "dynamic/spectrums/00005.png").unlink(), "image 00005.png is missing"),
    (lambda o: (o / "static/spectrum/00002.png").unlink(), "image 00002.png is missing"),
    (lambda o: _edit(o / "dynamic/spectrum_info.csv", ",0\n2,", ",1\n2,"), "holds two poses of the person"),
    (lambda o: (o / "static/rx_info.csv").write_text("x,y,z\n" + "9,9,9\n" * 4), "is not one of the positions"),
    (lambda o: (o / "dynamic/spectrum_info.csv").write_text(
        "\n".join((o / "dynamic/spectrum_info.csv").read_text().splitlines()[:-1]) + "\n"),
     "has no spectrum at rx_info.csv row 4"),
    (lambda o: (o / "dynamic/spectrum_info.csv").write_text(
        (o / "dynamic/spectrum_info.csv").read_text().replace(",0,0,", ",0,", 1)), "cells, the header has 12"),
    (lambda o: (o / "static/gateway_info.yml").unlink() or _published(o), "fixed device's position is not stated"),
    (lambda o: (o / "static" / nerf2.EXTRA).write_text('{"frequency_hz": -1}'), "frequency_hz must be a positive"),
    (lambda o: (o / "dynamic/train_index.txt").write_text("00099\n"), "image 00099 is not in spectrum_info.csv"),
    (lambda o: shutil.rmtree(o / "static"), "no static folder"),
])
def test_bad_folders_name_the_problem(pair, change, message):
    src, out = pair
    change(out)
    with pytest.raises(DatasetError, match=message) as e:
        D.open_dataset(out)
    assert str(out) in str(e.value)


def test_not_a_one_walk_folder(tmp_path):
    assert ow.layout(tmp_path) is None
    with pytest.raises(DatasetError, match="not a One Walk folder"):
        ow.read(tmp_path)


# --------------------------------------------------------------------------- fuzzing
FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
number = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32), st.integers(-10**6, 10**6))
token = st.one_of(number.map(str), st.sampled_from(["", "nan", "inf", "-0", "1e999", "00001", "٣", "1_0"]),
                  st.text(alphabet="0123456789.-+eE ,x\t\r\"#:[]{}'abc", max_size=8))
line = st.lists(token, min_size=0, max_size=13).map(lambda t: ",".join(t))
text_file = st.one_of(
    st.lists(line, max_size=8).map(lambda ls: "\n".join(ls)),
    st.lists(line, max_size=8).map(lambda ls: "\r\n".join(ls)),
    st.binary(max_size=64).map(lambda b: b.decode("latin-1")),
)
FILES = ["static/rx_info.csv", "static/train_index.txt", "static/test_index.txt", "static/gateway_info.yml",
         "static/rfmitsuba.json", "dynamic/spectrum_info.csv", "dynamic/train_index.txt", "dynamic/val_index.txt",
         "dynamic/test_index.txt", "dynamic/rfmitsuba.json"]


@pytest.fixture(scope="module")
def fuzz_folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("one_walk_fuzz")
    src, out = _pair(root)
    good = root / "good"
    shutil.copytree(out, good)
    return out, good


def _reset(out, good):
    shutil.rmtree(out)
    shutil.copytree(good, out)


def _check(out):
    try:
        ds = ow.read(out)
    except DatasetError as e:
        assert str(out) in str(e)
        return
    S = ds.num_states
    assert ds.antenna_pos.shape == (A, 3) and np.isfinite(ds.antenna_pos).all() and np.isfinite(ds.fixed_pos).all()
    assert ds.person_pos.shape == (S, 3) and np.isfinite(ds.person_pos[1:]).all()
    assert np.isfinite(ds.frequency_hz) and np.allclose(ds.rx_to_world @ ds.rx_to_world.T, np.eye(3), atol=1e-6)
    sp = ds.split
    assert not np.intersect1d(sp.antenna_train, sp.antenna_test).size
    assert not np.intersect1d(sp.person_train, sp.person_test).size
    assert np.asarray(ds.pas(S - 1)).shape == (A, 90, 360)


@FUZZ
@given(text=text_file, name=st.sampled_from(FILES))
def test_any_text_file_reads_or_raises_dataset_error(fuzz_folder, text, name):
    out, good = fuzz_folder
    _reset(out, good)
    (out / name).write_bytes(text.encode("utf-8", "surrogatepass"))
    _check(out)


#: edits of a good spectrum_info.csv: (row or -1 for the header, column or -1, what to do)
edit = st.tuples(st.integers(-1, A * H - 1), st.integers(-1, 11),
                 st.one_of(token, st.sampled_from(["<drop column>", "<duplicate row>", "<drop row>", "<swap>"])))


@FUZZ
@given(edits=st.lists(edit, min_size=1, max_size=4), drop_images=st.sets(st.integers(1, A * H), max_size=2),
       drop_static=st.sets(st.integers(1, A), max_size=1))
def test_damaged_spectrum_info_reads_or_raises_dataset_error(fuzz_folder, edits, drop_images, drop_static):
    out, good = fuzz_folder
    _reset(out, good)
    f = out / "dynamic" / "spectrum_info.csv"
    table = [ln.split(",") for ln in f.read_text().splitlines()]
    for row, col, what in edits:
        r = row + 1
        if what == "<drop column>" and col >= 0:
            for cells in table:
                cells.pop(min(col, len(cells) - 1)) if cells else None
        elif what == "<duplicate row>" and r > 0:
            table.insert(r, list(table[min(r, len(table) - 1)]))
        elif what == "<drop row>" and 0 < r < len(table):
            table.pop(r)
        elif what == "<swap>" and 0 < r < len(table) - 1:
            table[r], table[r + 1] = table[r + 1], table[r]
        elif r < len(table) and 0 <= col < len(table[r]):
            table[r][col] = what
    f.write_text("\n".join(",".join(c) for c in table) + "\n")
    for n in drop_images:
        (out / "dynamic" / "spectrums" / f"{n:05d}.png").unlink()
    for n in drop_static:
        (out / "static" / "spectrum" / f"{n:05d}.png").unlink()
    _check(out)


def test_fingerprint_follows_content_not_place(pair, tmp_path):
    src, out = pair
    fp = ow.read(out).fingerprint()
    moved = tmp_path / "moved"
    shutil.copytree(out, moved)
    assert ow.read(moved).fingerprint() == fp
    (moved / "dynamic" / "val_index.txt").write_text("")
    assert ow.read(moved).fingerprint() != fp
