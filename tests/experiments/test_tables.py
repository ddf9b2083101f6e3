"""rfmitsuba.experiments.tables: the knee of a parsimony curve, and the coherent Gaussian field's curve."""
from __future__ import annotations



def test_knee_on_hand_made_curves():
    from rfmitsuba.experiments.tables import knee

    # rises steeply to 64 Gaussians, then flat: the knee is 64
    assert knee([8, 16, 32, 64, 128, 256], [0.70, 0.80, 0.88, 0.93, 0.935, 0.936]) == 3
    assert knee([8, 16, 32], [0.9, 0.8, 0.7]) == 0  # falling: the smallest is best
    assert knee([8, 16], [0.8, 0.9]) == 1  # too short for a knee: the best


def test_parsimony_curve_of_the_coherent_gaussian_field(tmp_path):
    from stage1_data import make_dataset
    from test_trainer import tiny_cfg

    from rfmitsuba.experiments.tables import parsimony_curve

    ds = make_dataset(tmp_path / "ds", num_antennas=30, task="tx")
    cfg = tiny_cfg(model='"coherent_gaussians"', iterations=4, val_every=4, checkpoint_every=4)
    rows = parsimony_curve(ds, tmp_path / "par", caps=(0, 3), cfg=cfg, quiet=True)
    assert rows[1]["num_gaussians"] - rows[0]["num_gaussians"] == 3
    text = (tmp_path / "par" / "table.md").read_text()
    assert "Knee" in text and "IDW-3" in text and (tmp_path / "par" / "parsimony.png").is_file()
    assert all(0 < r["idw3_mean"] <= 1 for r in rows)
