"""A run keeps the content fingerprint of its dataset: ``eval`` and ``predict`` warn when the
data changed after training instead of scoring the field against other data silently."""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from rfmitsuba import cli


def test_eval_and_predict_warn_when_a_spectrum_changed_after_training(synthetic_ds, tmp_path, capsys):
    from PIL import Image

    from rfmitsuba.data import nerf2
    from rfmitsuba.data.store import open_dataset

    folder = nerf2.write(open_dataset(synthetic_ds), tmp_path / "nerf2")
    run = tmp_path / "run"
    args = ["train", str(folder), "--out", str(run), "--model", "splat", "--quiet"]
    for s in ["iterations=10", "downsample=5", "val_every=5", "splat.init=\"random\"", "splat.num_gaussians=40",
              "splat.net.width=8"]:
        args += ["--set", s]
    assert cli.main(args) == 0
    fp = json.loads((run / "run.json").read_text())["dataset_fingerprint"]
    assert isinstance(fp, str) and len(fp) == 64
    from rfmitsuba.train.trainer import load_run

    with warnings.catch_warnings(record=True) as seen:    # unchanged data: no warning of a change
        warnings.simplefilter("always")
        load_run(run)
    assert not [w for w in seen if "has changed" in str(w.message)]
    test_image = folder / "spectrum" / f"{int((folder / 'test_index.txt').read_text().split()[0]):05d}.png"
    img = np.asarray(Image.open(test_image))
    Image.fromarray((255 - img).astype(np.uint8), mode="L").save(test_image)
    with pytest.warns(UserWarning, match="has changed since .* was trained"):
        assert cli.main(["eval", str(run)]) == 0
    # the warning stays with the evaluation it concerns, not only on the terminal
    assert any("has changed since" in w for w in json.loads((run / "eval" / "metrics.json").read_text())["warnings"])
    assert "**Warning:**" in (run / "eval" / "summary.md").read_text()
    pos = tmp_path / "p.csv"
    pos.write_text("0.5 0.5 1.0\n")
    with pytest.warns(UserWarning, match="has changed since"):
        cli.main(["predict", str(run), "--positions", str(pos), "--out", str(tmp_path / "pred")])
    capsys.readouterr()
