"""Tests of rfmitsuba.eval.metrics: SSIM protocol, floors on hand-made cases, the run report."""
from __future__ import annotations

import json

import numpy as np
import pytest


def _img(seed, h=20, w=30):
    return np.random.default_rng(seed).random((h, w)).astype(np.float32)


def test_ssim_images_is_skimage_per_image():
    from skimage.metrics import structural_similarity

    from rfmitsuba.core.ssim import ssim_images

    a = np.stack([_img(0), _img(1)])
    b = np.stack([_img(0), _img(2)])
    s = ssim_images(a, b)
    assert s[0] == pytest.approx(1.0)
    assert s[1] == pytest.approx(structural_similarity(a[1].astype(np.float64), b[1].astype(np.float64),
                                                       data_range=1.0))
    with pytest.raises(ValueError, match="must both be"):
        ssim_images(a, b[:1])


def test_nearest_index_with_and_without_human():
    from rfmitsuba.eval.metrics import nearest_index

    train = np.array([[0, 0, 0], [1, 0, 0], [5, 5, 1.0]])
    q = np.array([[0.9, 0.1, 0], [4, 4, 1], [0.2, 0, 0]])
    np.testing.assert_array_equal(nearest_index(train, q), [1, 2, 0])
    # with human positions the nearest sample is the one with the closer human
    train2 = np.array([[0, 0, 0], [0, 0, 0.0]])
    th = np.array([[3, 3, 0], [1, 1, 0.0]])
    np.testing.assert_array_equal(nearest_index(train2, np.zeros((1, 3)), train_human=th,
                                                query_human=np.array([[1.2, 1, 0]])), [1])


def test_floors_on_hand_made_cases():
    """Test image k equals training image k, placed at the training position plus 1 cm: the
    nearest-neighbour floor is exactly 1; the mean-image floor compares with the normalised mean."""
    from rfmitsuba.core.ssim import ssim_images
    from rfmitsuba.eval.metrics import floors
    from rfmitsuba.rf.bartlett_ref import normalize as minmax

    train = minmax(np.stack([_img(i) for i in range(4)]))
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    test = train[[2, 0]]
    f = floors(train, pos, test, pos[[2, 0]] + 0.01)
    np.testing.assert_allclose(f["nearest_neighbour"], 1.0)
    np.testing.assert_array_equal(f["nearest_index"], [2, 0])
    mean = minmax(train.mean(0)[None])[0]
    np.testing.assert_allclose(f["mean_image"], ssim_images(np.stack([mean, mean]), test))
    assert np.all(f["mean_image"] < 0.9)


def test_minmax_and_stats():
    from rfmitsuba.eval.metrics import stats
    from rfmitsuba.rf.bartlett_ref import normalize as minmax

    x = np.stack([np.full((3, 3), 5.0), np.arange(9.0).reshape(3, 3)])
    m = minmax(x)
    assert m[0].max() == 0 and m[1].min() == 0 and m[1].max() == 1
    s = stats(np.array([0.1, 0.5, 0.9, 0.3]))
    assert s["mean"] == pytest.approx(0.45) and s["median"] == pytest.approx(0.4) and s["n"] == 4


def test_evaluate_run_writes_report(tmp_path, variant):
    from stage1_data import make_dataset
    from test_trainer import tiny_cfg

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
    for f in ["summary.md", "metrics.json", "ssim.npz", "grid.png", "ssim_cdf.png", "ssim_vs_time.png"]:
        assert (out / f).is_file(), f
    assert m["test_positions"] == 6 and 0 < m["nearest_neighbour"]["mean"] <= 1
    assert json.loads((out / "metrics.json").read_text())["num_gaussians"] == m["num_gaussians"]
    text = (out / "summary.md").read_text()
    assert "nearest neighbour" in text and "mean image" in text and "wall time" in text
    with np.load(out / "ssim.npz") as z:
        assert z["model"].shape == (6,)
        assert m["model"]["mean"] == pytest.approx(float(z["model"].mean()))
    assert main(["eval", str(run)]) == 0


def test_motivation_table_and_parsimony_on_a_tiny_dataset(tmp_path, variant):
    """Two rows each; the table files exist and rows carry model and floor numbers."""
    from stage1_data import make_dataset
    from test_trainer import tiny_cfg

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
