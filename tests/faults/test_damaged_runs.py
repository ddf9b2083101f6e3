"""A damaged checkpoint or final field is named, with the way out, instead of a raw
``zipfile.BadZipFile`` traceback."""
from __future__ import annotations

import pytest

from rfmitsuba import cli

SETS = ["iterations=20", "downsample=5", "val_every=10", "checkpoint_every=10", "log_every=5",
        "splat.init=\"random\"", "splat.num_gaussians=60", "splat.net.width=8"]


def _truncate(path, keep=0.5):
    data = path.read_bytes()
    path.write_bytes(data[:int(len(data) * keep)])


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory, synthetic_ds):
    out = tmp_path_factory.mktemp("damaged") / "run"
    args = ["train", str(synthetic_ds), "--out", str(out), "--model", "splat", "--quiet"]
    for s in SETS:
        args += ["--set", s]
    assert cli.main(args) == 0
    return out, args


def test_a_truncated_final_field_is_named_with_the_way_out(finished_run, tmp_path, capsys):
    import shutil

    out, _ = finished_run
    run = tmp_path / "run"
    shutil.copytree(out, run)
    _truncate(run / "final" / "field.npz")
    assert cli.main(["eval", str(run)]) == 2
    err = capsys.readouterr().err
    assert "field.npz" in err and "delete" in err and "Traceback" not in err


def test_training_a_finished_run_again_checks_its_field(finished_run, tmp_path, capsys):
    """The same ``train`` on a finished run whose final field was truncated does not report the
    old summary as a success: it names the file and the way out, and the way out (delete final/,
    train again) writes a readable field from the checkpoint."""
    import shutil

    from rfmitsuba.models.base import load_field

    out, args = finished_run
    run = tmp_path / "run"
    shutil.copytree(out, run)
    _truncate(run / "final" / "field.npz")
    again = ["train", args[1], "--out", str(run)] + args[4:]
    assert cli.main(again) == 2
    err = capsys.readouterr().err
    assert "field.npz: not a readable field file" in err and "delete" in err and "Traceback" not in err
    shutil.rmtree(run / "final")
    assert cli.main(again) == 0
    load_field(run / "final" / "field.npz")


def test_a_truncated_checkpoint_is_named_with_the_way_out(finished_run, tmp_path, capsys):
    from rfmitsuba.core import config as C
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.config import TrainConfig
    from rfmitsuba.train.trainer import Trainer

    out, args = finished_run
    cfg = C.override(TrainConfig(model="splat"), SETS)
    data = TrainData.open(args[1])
    run = tmp_path / "stopped"
    assert Trainer(cfg, data, run, quiet=True).run(stop_at=15)["stopped"] == "stop_at"
    _truncate(run / "checkpoint" / "state.npz")
    resume = ["train", args[1], "--out", str(run)] + args[4:]
    assert cli.main(resume) == 2
    err = capsys.readouterr().err
    assert "state.npz" in err and "checkpoint is damaged" in err and "Traceback" not in err
    assert (run / "checkpoint").is_dir()                 # nothing was deleted for the user
