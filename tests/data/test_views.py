"""rfmitsuba.data.views: TrainData reads the simulating tracer's depth from the dataset, and places the
fixed and moving devices for any position (positions_at)."""
from __future__ import annotations

import json

import pytest


def _with_solver(folder, solver):
    meta = json.loads((folder / "meta.json").read_text())
    if solver is None:
        meta.pop("solver", None)
    else:
        meta["solver"] = solver
    (folder / "meta.json").write_text(json.dumps(meta))


def test_max_depth_comes_from_the_dataset_solver(tmp_path):
    from stage1_data import make_dataset

    from rfmitsuba.core.errors import DatasetError
    from rfmitsuba.data.views import TrainData

    ds = make_dataset(tmp_path / "ds", num_antennas=12)
    _with_solver(ds, {"max_depth": 3, "refraction": True})
    assert TrainData.open(ds).max_depth == 3
    _with_solver(ds, None)
    assert TrainData.open(ds).max_depth is None                     # no tracer named: no limit
    for bad in ("3", -1, 2.5, True):
        _with_solver(ds, {"max_depth": bad})
        with pytest.raises(DatasetError, match="solver.max_depth"):
            TrainData.open(ds)


def test_min_segment_comes_from_the_dataset_solver(tmp_path):
    """A dataset made by a tracer gets Sionna RT's shortest segment unless it states its own;
    one made by none (measured data) gets no limit; a bad value is named."""
    from stage1_data import make_dataset

    from rfmitsuba.core.errors import DatasetError
    from rfmitsuba.data.views import SIONNA_MIN_SEGMENT_M, TrainData

    ds = make_dataset(tmp_path / "ds", num_antennas=12)
    _with_solver(ds, {"max_depth": 3})
    assert TrainData.open(ds).min_segment == SIONNA_MIN_SEGMENT_M == 0.01
    _with_solver(ds, {"max_depth": 3, "min_segment_m": 0.002})
    assert TrainData.open(ds).min_segment == 0.002
    _with_solver(ds, None)
    assert TrainData.open(ds).min_segment is None
    for bad in ("1", -0.01, float("nan"), True):
        _with_solver(ds, {"max_depth": 3, "min_segment_m": bad})
        with pytest.raises(DatasetError, match="solver.min_segment_m"):
            TrainData.open(ds)


def test_spectra_vary_by_measurement_where_no_tracer_made_them_or_a_drift_was_simulated(tmp_path):
    """A dataset made by a ray tracer does not vary by measurement; one whose metadata names no
    tracer (measured spectra) does, and so does a simulation with a measurement drift; a NeRF2
    folder as published does, and one whose rfmitsuba.json records a tracer (a NeRF2-like
    simulation) does only with a drift."""
    from stage1_data import make_dataset

    from rfmitsuba.data import nerf2
    from rfmitsuba.data.store import open_dataset
    from rfmitsuba.data.views import TrainData

    ds = make_dataset(tmp_path / "ds", num_antennas=12, task="tx")
    _with_solver(ds, {"max_depth": 3})
    assert TrainData.open(ds).varies_by_measurement is False
    meta = json.loads((ds / "meta.json").read_text())
    (ds / "meta.json").write_text(json.dumps(meta | {"impairments": {"drift": {"magnitude_db": 8.0}}}))
    assert TrainData.open(ds).varies_by_measurement is True
    (ds / "meta.json").write_text(json.dumps(meta | {"impairments": {"drift": None}}))
    assert TrainData.open(ds).varies_by_measurement is False
    _with_solver(ds, None)
    assert TrainData.open(ds).varies_by_measurement is True
    folder = nerf2.write(open_dataset(ds), tmp_path / "n")
    extra = folder / "rfmitsuba.json"
    own = json.loads(extra.read_text())
    for solver, drift, varies in ((None, None, True), ({"max_depth": 3}, None, False),
                                  ({"max_depth": 3}, {"magnitude_db": 7.0}, True)):
        extra.write_text(json.dumps({k: v for k, v in own.items() if k not in ("solver", "impairments")}
                                    | ({"solver": solver} if solver else {}) | {"impairments": {"drift": drift}}))
        d = TrainData.open(folder)
        assert (d.measured, d.varies_by_measurement) == (False, varies), (solver, drift)
    extra.unlink()                                   # as published
    d = TrainData.open(folder)
    assert d.measured and d.varies_by_measurement


def test_sionna_min_segment_is_the_installed_sionnas():
    """The constant the datasets are read with is the one the installed Sionna RT drops paths by."""
    pytest.importorskip("sionna.rt")
    from sionna.rt.constants import MIN_SEGMENT_LENGTH

    from rfmitsuba.data.views import SIONNA_MIN_SEGMENT_M

    assert SIONNA_MIN_SEGMENT_M == pytest.approx(float(MIN_SEGMENT_LENGTH))


@pytest.mark.parametrize("task", ["rx", "tx"])
def test_positions_at_agrees_with_positions(tmp_path, task):
    """At the dataset's own positions, positions_at gives what positions gives: the moving device
    moved, the fixed one where the dataset has it."""
    import numpy as np
    from stage1_data import make_dataset

    from rfmitsuba.data.views import TrainData

    d = TrainData.open(make_dataset(tmp_path / "ds", num_antennas=12, task=task))
    idx = np.array([3, 0, 11])
    x, y, q = d.positions(idx)
    xa, ya = d.positions_at(q)
    np.testing.assert_array_equal(xa, x)
    np.testing.assert_array_equal(ya, y)
    moved = q + [0.1, -0.2, 0.05]
    xm, ym = d.positions_at(moved)
    np.testing.assert_array_equal(xm if task == "rx" else ym, moved)
    np.testing.assert_array_equal(ym if task == "rx" else xm, y if task == "rx" else x)


def test_pas_in_chunks_keeps_the_order_asked_for(tmp_path, monkeypatch):
    """TrainData.pas goes through views.normalised_pas a chunk at a time, reading each chunk's rows
    sorted: with chunks of 5 and the indices shuffled (one repeated), every image is the normalised
    block mean of its own antenna's raw PAS."""
    import numpy as np
    from stage1_data import make_dataset

    from rfmitsuba.data import views
    from rfmitsuba.data.views import TrainData, downsample
    from rfmitsuba.rf.bartlett_ref import normalize

    data = TrainData.open(make_dataset(tmp_path / "ds", num_antennas=12))
    idx = np.array([7, 2, 11, 0, 5, 5, 9, 1, 3, 10, 4, 6, 8])
    whole = normalize(downsample(np.asarray(data._pas, np.float32)[idx], 3))
    monkeypatch.setattr(views, "PAS_CHUNK", 5)
    np.testing.assert_allclose(data.pas(idx, d=3), whole, atol=1e-6)
