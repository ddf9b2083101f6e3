"""rfmitsuba.data.views: TrainData reads the simulating tracer's depth from the dataset."""
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
