"""Tests of rfmitsuba.eval.predict (``rfmitsuba predict``): positions files, renders at chosen
positions that match the run's own renders at its dataset's positions (both tasks), the anchored
prediction, the room check and the output folder."""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st


def test_read_positions_accepts_published_layouts(tmp_path):
    from rfmitsuba.eval.predict import read_positions

    p = tmp_path / "tx_pos.csv"
    p.write_bytes(b"x,y,z\r\n1.0,2.0,0.5\r\n\r\n3,4,5\r\n")
    np.testing.assert_array_equal(read_positions(p), [[1.0, 2.0, 0.5], [3.0, 4.0, 5.0]])
    q = tmp_path / "grid.txt"
    q.write_text("id z y x\n7 1 0 0\n8 1\t0.25  0.5\n")                  # a header naming the columns
    np.testing.assert_array_equal(read_positions(q), [[0, 0, 1], [0.5, 0.25, 1]])
    n = tmp_path / "pos.npy"
    np.save(n, np.array([[1.0, 1.0, 1.0]]))
    assert read_positions(n).shape == (1, 3)


@pytest.mark.parametrize("text, match", [
    ("x,y,z\n1,2\n", r"bad\.csv:2: expected numbers x,y,z"),
    ("1,2,3\n4,five,6\n", r"bad\.csv:2: expected numbers x,y,z"),
    ("1,2,3\nnan,0,0\n", r"bad\.csv:2: position is not finite"),
    ("x,y,z\n", "a header row and no positions"),
])
def test_read_positions_names_the_bad_line(tmp_path, text, match):
    from rfmitsuba.core.errors import DatasetError
    from rfmitsuba.eval.predict import read_positions

    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(DatasetError, match=match):
        read_positions(p)


def test_read_positions_refuses_bad_arrays(tmp_path):
    from rfmitsuba.core.errors import DatasetError
    from rfmitsuba.eval.predict import read_positions

    with pytest.raises(DatasetError, match="does not exist"):
        read_positions(tmp_path / "none.csv")
    (tmp_path / "bin.csv").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(DatasetError, match="not a UTF-8 text file"):
        read_positions(tmp_path / "bin.csv")
    np.save(tmp_path / "a.npy", np.zeros((4, 2)))
    with pytest.raises(DatasetError, match=r"shape \[K, 3\]"):
        read_positions(tmp_path / "a.npy")
    np.save(tmp_path / "b.npy", np.array([[0.0, np.inf, 0.0]]))
    with pytest.raises(DatasetError, match="row 0 is not finite"):
        read_positions(tmp_path / "b.npy")
    (tmp_path / "c.npy").write_bytes(b"not numpy")
    with pytest.raises(DatasetError, match="not a NumPy array"):
        read_positions(tmp_path / "c.npy")


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=200))
def test_read_positions_fuzz(tmp_path_factory, blob):
    """Any bytes either read as finite positions [K, 3] or raise DatasetError, nothing else."""
    from rfmitsuba.core.errors import DatasetError
    from rfmitsuba.eval.predict import read_positions

    p = tmp_path_factory.mktemp("fuzz") / "pos.csv"
    p.write_bytes(blob)
    try:
        a = read_positions(p)
    except DatasetError:
        return
    assert a.ndim == 2 and a.shape[1] == 3 and len(a) >= 1 and np.isfinite(a).all()


@pytest.mark.parametrize("task", ["rx", "tx"])
def test_prediction_matches_the_runs_render_at_its_positions(tmp_path, task, capsys):
    """At the dataset's own positions the prediction is the run's normalised render there: the
    views are built as the dataset's (array or transmitter moved, the fixed device kept)."""
    from stage1_data import make_dataset
    from stage1_data import tiny_cfg

    from rfmitsuba.cli import main
    from rfmitsuba.core.errors import RunError
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.eval.predict import predict_run
    from rfmitsuba.rf.bartlett_ref import normalize
    from rfmitsuba.train.trainer import Trainer, load_run

    ds = make_dataset(tmp_path / "ds", num_antennas=30, task=task)
    run = tmp_path / "run"
    Trainer(tiny_cfg(iterations=10), TrainData.open(ds), run, quiet=True).run()
    _, data, renderer = load_run(run)
    idx = np.array([0, 7, 19])
    res = predict_run(run, data.antenna_pos[idx])
    assert res["pas"].shape == (3, 90, 360) and res["how"] == "field" and res["task"] == task
    np.testing.assert_allclose(res["pas"], normalize(renderer.render(data, idx)), atol=2e-5)
    with pytest.raises(RunError, match="rfmitsuba eval"):
        predict_run(run, data.antenna_pos[idx], anchor=True)
    np.savetxt(tmp_path / "pos.csv", data.antenna_pos[idx], delimiter=",", header="x,y,z", comments="")
    out = tmp_path / "pred"
    assert main(["predict", str(run), "--positions", str(tmp_path / "pos.csv"), "--out", str(out)]) == 0
    np.testing.assert_allclose(np.load(out / "pas.npy"), res["pas"], atol=1e-6)
    assert len(list((out / "spectrum").glob("*.png"))) == 3
    assert json.loads((out / "predict.json").read_text())["count"] == 3
    assert main(["predict", str(run), "--positions", str(tmp_path / "pos.csv"), "--out", str(out)]) != 0
    assert "not an empty folder" in capsys.readouterr().err


def test_anchored_prediction_and_room_check(tmp_path):
    from stage1_data import known_field, render_pas
    from stage1_data import tiny_cfg

    from rfmitsuba.core.errors import PlacementError
    from rfmitsuba.data.store import write_dataset
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.eval.anchor import anchored
    from rfmitsuba.eval.predict import predict_run
    from rfmitsuba.eval.run import evaluate_run
    from rfmitsuba.rf.bartlett_ref import normalize
    from rfmitsuba.train.trainer import Trainer, load_run

    rng = np.random.default_rng(3)
    ap = rng.uniform([1.0, 1.0, 0.8], [3.0, 2.5, 1.6], (30, 3))
    write_dataset(tmp_path / "ds", pas=render_pas(known_field(), ap, ap)[None], antenna_pos=ap,
                  person_pos=np.full((1, 3), np.nan), meta={"task": "rx", "fixed_pos": [0.3, 0.3, 2.0],
                                                           "scene": "bedroom"}, seed=0)
    run = tmp_path / "run"
    Trainer(tiny_cfg(iterations=10), TrainData.open(tmp_path / "ds"), run, quiet=True).run()
    with pytest.raises(PlacementError, match=r"position 1 at \(10\.000, 1\.000, 1\.000\).*--no-room-check renders it anyway"):
        predict_run(run, np.array([[2.0, 1.5, 1.2], [10.0, 1.0, 1.0]]))
    assert predict_run(run, np.array([[10.0, 1.0, 1.0]]), check_room=False)["pas"].shape == (1, 90, 360)
    m = evaluate_run(run)
    q = np.array([[2.0, 1.5, 1.2], [1.5, 2.0, 1.0]])
    res = predict_run(run, q, anchor=True)
    ch = m["anchored"]
    # a 10-step field loses to its neighbours on validation: the anchored branch is the one tested
    assert ch["use"] == "anchored", ch
    _, data, renderer = load_run(run)
    tr = np.asarray(json.loads((run / "split.json").read_text())["train"])
    want = anchored(predict_run(run, q)["pas"], normalize(renderer.render(data, tr)), data.pas(tr),
                    data.antenna_pos[tr], q, k=ch["k"], alpha=ch["alpha"])
    np.testing.assert_allclose(res["pas"], want, atol=1e-5)
    assert res["how"].startswith("anchored k=")


def test_room_box_of_an_unknown_room_refuses_positions_outside_it():
    """A run of an unknown room trained with ``coherent_gaussians.room_box``: predict refuses a
    position outside that box, naming it; inside it, or without a box, nothing is refused."""
    from types import SimpleNamespace

    from rfmitsuba.core.errors import PlacementError
    from rfmitsuba.eval.predict import _check_room_box

    boxed = SimpleNamespace(fields=[SimpleNamespace(cfg=SimpleNamespace(room_box=(0.0, 0.0, 0.0, 4.4, 3.5, 2.8)))])
    inside = np.array([[1.0, 1.0, 1.0], [4.4, 3.5, 0.0]])
    _check_room_box(boxed, inside)
    _check_room_box(SimpleNamespace(fields=[SimpleNamespace(cfg=SimpleNamespace(room_box=None))]),
                    np.array([[9.0, 9.0, 9.0]]))
    with pytest.raises(PlacementError, match=r"position 1 at \(5.000, 1.000, 1.000\) is outside the room box "
                                             r"\[0.0, 0.0, 0.0, 4.4, 3.5, 2.8\] m .* \(1 more position"):
        _check_room_box(boxed, np.array([[1.0, 1.0, 1.0], [5.0, 1.0, 1.0], [1.0, 1.0, -0.1]]))


def test_an_unknown_room_without_a_box_refuses_positions_far_from_its_data():
    from types import SimpleNamespace

    from rfmitsuba.core.errors import PlacementError
    from rfmitsuba.eval.predict import UNKNOWN_ROOM_MARGIN_M, _check_room_box

    data = SimpleNamespace(antenna_pos=np.array([[0.0, 0.0, 1.0], [0.5, 1.0, 1.2]], np.float32))
    unboxed = SimpleNamespace(fields=[SimpleNamespace(cfg=SimpleNamespace(room_box=None))])
    _check_room_box(unboxed, np.array([[0.5 + UNKNOWN_ROOM_MARGIN_M - 0.01, -0.9, 0.3]]), data)
    for far in ([100.0, 100.0, 100.0], [1e30, 1e30, 1e30], [0.0, 0.0, 1.2 + UNKNOWN_ROOM_MARGIN_M + 0.01]):
        with pytest.raises(PlacementError, match=r"position 1 .* outside the box of the run's training positions"):
            _check_room_box(unboxed, np.array([[0.0, 0.0, 1.0], far]), data)


def test_predict_never_writes_a_constant_image(tmp_path, monkeypatch):
    """A field that renders a constant image somewhere is refused there (min-max normalising it
    would write zeros as a PAS), naming the position."""
    from rfmitsuba.core.errors import RunError
    from rfmitsuba.eval import predict as P

    data = type("D", (), {"scene_xml": None, "antenna_pos": np.zeros((2, 3), np.float32), "path": tmp_path,
                          "task": "tx"})()
    monkeypatch.setattr(P, "load_run", lambda rd: (None, data, type("R", (), {"fields": []})()))

    def render(renderer, d, q, batch):
        out = np.random.default_rng(0).random((len(q), 90, 360)).astype(np.float32)
        out[1] = 0.25
        return out

    monkeypatch.setattr(P, "render_at", render)
    with pytest.raises(RunError, match=r"constant .* position 1 \(0.100, 0.000, 0.000\)"):
        P.predict_run(tmp_path, np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]]))


def test_a_gaussian_process_run_predicts_with_its_uncertainty(tmp_path):
    """predict on a Gaussian-process run: the spectra at the training positions are the field's own,
    predict.json carries each position's predictive standard deviation, small at a training position
    and larger between them, never above the prior's."""
    from rfmitsuba.data import nerf2
    from rfmitsuba.data.store import open_dataset
    from rfmitsuba.eval.predict import predict_run, write_prediction
    from rfmitsuba.train.trainer import load_run, train
    from stage1_data import make_dataset, tiny_cfg

    folder = nerf2.write(open_dataset(make_dataset(tmp_path / "tx", num_antennas=40, task="tx")), tmp_path / "n")
    (folder / nerf2.EXTRA).unlink()
    run = tmp_path / "run"
    train(folder, run, cfg=tiny_cfg(model='"gaussian_process"'), quiet=True)
    _, data, renderer = load_run(run)
    gp = renderer.fields[0]
    at = gp.positions[:2]
    between = (gp.positions[:1] + gp.positions[1:2]) / 2 + 0.05
    r = predict_run(run, np.r_[at, between])
    assert r["pas"].shape == (3, 90, 360) and r["predictive_sd"].shape == (3,)
    assert r["predictive_sd"][:2].max() < r["predictive_sd"][2] <= r["prior_sd"]
    out = write_prediction(tmp_path / "pred", r)
    rec = json.loads((out / "predict.json").read_text())
    assert rec["predictive_sd"] == pytest.approx(r["predictive_sd"].tolist()) and rec["prior_sd"] == r["prior_sd"]
