"""CLI ``rfmitsuba export``: a dataset written in the One Walk layout (and NeRF2's), which ``train``,
``eval`` and ``compare`` then read as they are."""
import json

import numpy as np

TINY = ["--set", "iterations=40", "--set", "downsample=5", "--set", "val_every=10", "--set", "checkpoint_every=10",
        "--set", "splat.init='random'", "--set", "splat.num_gaussians=100", "--model", "splat", "--quiet"]
TINY_COMPARE = ["--methods", "baseline,ours", "--seeds", "0", "--set", "train.stage1_iterations=8",
                "--set", "train.val_every=8", "--set", "train.stage2_iterations=6",
                "--set", "train.overrides=['coherent_person.num_points=4']"]


def test_export_one_walk_then_train_eval_and_compare(synthetic_ds, tmp_path, capsys):
    from rfmitsuba.cli import main
    from rfmitsuba.data.store import open_dataset

    out = tmp_path / "ow"
    assert main(["export", str(synthetic_ds), str(out), "--format", "one-walk"]) == 0
    text = capsys.readouterr().out
    assert f"{out / 'static'}: 30 spectra" in text and "180 spectra (6 frames x 30 positions)" in text
    assert (out / "static" / "spectrum" / "00030.png").is_file() and (out / "dynamic" / "spectrums" / "00180.png").is_file()
    rec = json.loads((out / "dynamic" / "rfmitsuba.json").read_text())
    assert rec["task"] == "rx" and rec["static"] == "../static" and rec["format"] == "rfmitsuba-one-walk/1"
    src, back = open_dataset(synthetic_ds), open_dataset(out)
    assert back.num_states == src.num_states and np.array_equal(back.split.person_test, src.split.person_test)
    # the static folder is a Stage-1 dataset: train and eval read it as it is
    assert main(["train", str(out / "static"), "--out", str(tmp_path / "run")] + TINY) == 0
    assert main(["eval", str(tmp_path / "run")]) == 0
    metrics = json.loads((tmp_path / "run" / "eval" / "metrics.json").read_text())
    assert metrics["model"]["n"] == len(src.split.antenna_test)
    # the pair is a dataset with person states
    assert main(["compare", str(out), "--out", str(tmp_path / "cmp")] + TINY_COMPARE) == 0
    res = json.loads((tmp_path / "cmp" / "results.json").read_text())
    assert sorted(r["method"] for r in res) == ["baseline", "ours"]
    # a folder that is not empty is refused, and --state belongs to --format nerf2
    capsys.readouterr()
    assert main(["export", str(synthetic_ds), str(out), "--format", "one-walk"]) == 2
    assert "is not empty" in capsys.readouterr().err
    assert main(["export", str(synthetic_ds), str(tmp_path / "x"), "--format", "one-walk", "--state", "1"]) == 2
    assert "--state is for --format nerf2" in capsys.readouterr().err


def test_export_nerf2_writes_one_state(synthetic_ds, tmp_path, capsys):
    from rfmitsuba.cli import main
    from rfmitsuba.data import nerf2

    out = tmp_path / "n2"
    assert main(["export", str(synthetic_ds), str(out), "--format", "nerf2", "--state", "2"]) == 0
    assert "30 spectra of state 2" in capsys.readouterr().out
    back = nerf2.read(out)
    assert back.num_antennas == 30 and back.task == "rx" and json.loads((out / "rfmitsuba.json").read_text())["state"] == 2
