"""Tests of rfmitsuba.eval.run: the run report with its three floors, and the motivation table."""
from __future__ import annotations

import json

import numpy as np
import pytest


def test_evaluate_run_writes_report(tmp_path, variant):
    from stage1_data import make_dataset
    from stage1_data import tiny_cfg

    from rfmitsuba.cli import main
    from rfmitsuba.core.errors import RunError
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.eval.run import evaluate_run
    from rfmitsuba.train.trainer import Trainer

    ds = make_dataset(tmp_path / "ds", num_antennas=30)
    run = tmp_path / "run"
    with pytest.raises(RunError, match="not a run folder"):
        evaluate_run(run)
    Trainer(tiny_cfg(iterations=10), TrainData.open(ds), run, quiet=True).run()
    m = evaluate_run(run)
    out = run / "eval"
    for f in ["summary.md", "metrics.json", "ssim.npz", "grid.png", "ssim_cdf.png", "ssim_vs_time.png",
              "ssim_map.png"]:
        assert (out / f).is_file(), f
    assert m["test_positions"] == 6 and 0 < m["nearest_neighbour"]["mean"] <= 1
    assert json.loads((out / "metrics.json").read_text())["num_gaussians"] == m["num_gaussians"]
    text = (out / "summary.md").read_text()
    assert "nearest neighbour" in text and "IDW-3" in text and "mean image" in text and "wall time" in text
    assert m["fit"]["n"] == 24 and 0 < m["fit"]["mean"] <= 1   # every training position (24 < FIT_POSITIONS)
    assert "generalisation gap" in text and "Where the model breaks" in text
    for dist in ("to_fixed_device", "to_nearest_training"):
        b = m["by_distance"][dist]
        assert sum(b["count"]) == 6
        assert np.average(b["model"], weights=b["count"]) == pytest.approx(m["model"]["mean"])
    assert m["best_floor"] in ("nearest_neighbour", "idw3") and 0 < m["idw3"]["mean"] <= 1
    with np.load(out / "ssim.npz") as z:
        assert z["model"].shape == (6,) and z["idw3"].shape == (6,)
        assert m["model"]["mean"] == pytest.approx(float(z["model"].mean()))
    assert main(["eval", str(run)]) == 0


def test_motivation_table_and_parsimony_on_a_tiny_dataset(tmp_path, variant):
    """Two rows each; the table files exist and rows carry model and floor numbers."""
    from stage1_data import make_dataset
    from stage1_data import tiny_cfg

    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.experiments.tables import motivation_table, parsimony_curve

    ds = make_dataset(tmp_path / "ds", num_antennas=40)
    cfg = tiny_cfg(iterations=5, val_every=5, checkpoint_every=5)
    rows = motivation_table(ds, tmp_path / "mot", counts=(10, 30), cfg=cfg, quiet=True)
    assert [r["positions"] for r in rows] == [10, 30] and [r["train_positions"] for r in rows] == [8, 24]
    assert (tmp_path / "mot" / "table.md").is_file() and (tmp_path / "mot" / "motivation.png").is_file()
    with pytest.raises(ConfigError, match="needs 80 training positions"):
        motivation_table(ds, tmp_path / "mot2", counts=(100,), cfg=cfg, quiet=True)
    rows = parsimony_curve(ds, tmp_path / "par", caps=(50, 100), cfg=cfg, quiet=True)
    assert all(r["num_gaussians"] <= r["cap"] for r in rows)
