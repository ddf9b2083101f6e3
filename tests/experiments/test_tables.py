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
    from stage1_data import tiny_cfg

    from rfmitsuba.experiments.tables import parsimony_curve

    ds = make_dataset(tmp_path / "ds", num_antennas=30, task="tx")
    # the scatterer cap alone (the plane pursuit, on for a walked room, would add planes to both rows)
    cfg = tiny_cfg(model='"coherent_gaussians"', iterations=4, val_every=4, checkpoint_every=4,
                   **{"coherent_gaussians.pursuit": '"off"'})
    rows = parsimony_curve(ds, tmp_path / "par", caps=(0, 3), cfg=cfg, quiet=True)
    assert rows[1]["num_gaussians"] - rows[0]["num_gaussians"] == 3
    text = (tmp_path / "par" / "table.md").read_text()
    assert "Knee" in text and "IDW-3" in text and (tmp_path / "par" / "parsimony.png").is_file()
    assert all(0 < r["idw3_mean"] <= 1 for r in rows)


def test_split_sensitivity_scores_every_field_and_floor_under_both_splits(tmp_path):
    """Both splits per field, the floors of each split, resumable, and a second call into the same
    folder adds a field with its own settings; the same field under other settings is refused
    unless a tag names them, and then joins as its own row (an ensemble here)."""
    import json

    import pytest
    from stage1_data import make_dataset
    from stage1_data import tiny_cfg

    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.experiments.tables import split_sensitivity

    ds = make_dataset(tmp_path / "ds", num_antennas=40, task="tx")
    out = tmp_path / "sp"
    with pytest.raises(ConfigError, match="coherent_gaussians_person.*person field"):
        split_sensitivity(ds, out, fields=("coherent_gaussians", "coherent_gaussians_person"), seeds=(0,),
                          cfg=tiny_cfg(), quiet=True)
    assert not out.exists()                                   # refused before any run started
    cfg = tiny_cfg(iterations=4, val_every=4, checkpoint_every=4, **{"coherent_gaussians.scatterers": 2})
    rows = split_sensitivity(ds, out, fields=("coherent_gaussians",), seeds=(0, 1), cfg=cfg, quiet=True)
    assert [(r["field"], r["split"], r["seeds"]) for r in rows] == [("coherent_gaussians", "dataset", 2),
                                                                     ("coherent_gaussians", "block", 2)]
    split = {r["split"]: r for r in rows}
    for sp in ("dataset", "block"):
        runs = sorted(out.glob(f"coherent_gaussians_{sp}_s*"))
        assert len(runs) == 2 and all(json.loads((r / "eval" / "metrics.json").read_text())["split"] == sp for r in runs)
    # the floors differ by split (other test positions), and the same split gives one floor for every seed
    assert split["dataset"]["nearest_neighbour"]["mean"] != split["block"]["nearest_neighbour"]["mean"]
    assert split["block"]["nearest_neighbour"]["mean"][1] == 0.0
    text = (out / "table.md").read_text()
    assert "| block (32/8) | coherent_gaussians | 2 |" in text and "nearest neighbour |" in text
    assert (out / "splits.png").is_file()
    # again: nothing is trained; a second field with other settings joins the table
    stamp = {p: p.stat().st_mtime_ns for p in out.rglob("field.npz")}
    rows2 = split_sensitivity(ds, out, fields=("splat",), seeds=(0,), cfg=tiny_cfg(iterations=6), quiet=True)
    assert all(p.stat().st_mtime_ns == t for p, t in stamp.items())
    assert [(r["field"], r["split"]) for r in rows2] == [("splat", "dataset"), ("coherent_gaussians", "dataset"),
                                                         ("splat", "block"), ("coherent_gaussians", "block")]
    assert {r["field"]: r["train_steps"] for r in rows2 if r["split"] == "block"} == {"splat": 6,
                                                                                      "coherent_gaussians": 4}
    import dataclasses

    from rfmitsuba.core.errors import RunError

    ens = dataclasses.replace(cfg, revert_drop=0.02)
    table = (out / "table.md").read_text()
    with pytest.raises(RunError, match=r"coherent_gaussians_dataset_s0 belongs to another configuration: "
                                       r"revert_drop \(run has 0.01, requested 0.02\)"):
        split_sensitivity(ds, out, fields=("coherent_gaussians",), seeds=(0,), cfg=ens, quiet=True)
    assert (out / "table.md").read_text() == table                     # nothing was changed
    with pytest.raises(ConfigError, match="tag 'revert 2'"):
        split_sensitivity(ds, out, fields=("coherent_gaussians",), seeds=(0,), cfg=ens, tag="revert 2", quiet=True)
    rows3 = split_sensitivity(ds, out, fields=("coherent_gaussians",), seeds=(0,), cfg=ens, tag="revert2",
                              quiet=True)
    by = {(r["field"], r["split"]): r for r in rows3}
    assert by["coherent_gaussians-revert2", "block"]["seeds"] == 1 and len(rows3) == 6
    assert (out / "coherent_gaussians-revert2_block_s0" / "final" / "field.npz").is_file()
    assert "| block (32/8) | coherent_gaussians-revert2 | 1 |" in (out / "table.md").read_text()
