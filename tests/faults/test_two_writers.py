"""Two writers into one folder: a second ``train`` or ``generate`` into a folder another live
process is writing is refused at once, naming that process, and changes nothing."""
from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from rfmitsuba import cli


@pytest.fixture
def other_writer(tmp_path):
    """A second live process holding a folder's lock, as a running ``train`` or ``generate`` does:
    yields (folder, pid)."""
    folder = tmp_path / "busy"
    ready = tmp_path / "ready"
    code = ("import sys, time, pathlib\n"
            "from rfmitsuba.core.folder_lock import folder_lock\n"
            "with folder_lock(sys.argv[1], what='train'):\n"
            "    pathlib.Path(sys.argv[2]).write_text('1')\n"
            "    time.sleep(120)\n")
    proc = subprocess.Popen([sys.executable, "-c", code, str(folder), str(ready)])
    try:
        for _ in range(600):
            if ready.exists():
                break
            if proc.poll() is not None:
                pytest.fail("the lock-holding process ended early")
            time.sleep(0.05)
        yield folder, proc.pid
    finally:
        proc.kill()
        proc.wait()


def _listing(folder):
    return sorted(p.name for p in folder.rglob("*"))


def test_a_second_train_is_refused_naming_the_first(other_writer, synthetic_ds, capsys):
    folder, pid = other_writer
    before = _listing(folder)
    assert cli.main(["train", str(synthetic_ds), "--out", str(folder), "--quick", "--model", "splat",
                     "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"pid {pid}" in err and str(folder) in err
    assert _listing(folder) == before                  # no log.jsonl, no config.toml


def test_a_second_generate_is_refused_naming_the_first(other_writer, capsys):
    folder, pid = other_writer
    before = _listing(folder)
    assert cli.main(["generate", "bedroom", "--task", "rx", "--quick", "--out", str(folder)]) == 2
    err = capsys.readouterr().err
    assert f"pid {pid}" in err and "generate" in err
    assert _listing(folder) == before                  # no meta.json, no chunk


def test_a_failed_first_train_leaves_no_folder(tmp_path, synthetic_ds, capsys):
    out = tmp_path / "run"
    # both fail with the lock held (the dataset and the scene are opened inside it)
    assert cli.main(["train", str(tmp_path / "missing"), "--out", str(out), "--quiet"]) == 2
    assert "missing" in capsys.readouterr().err
    assert not out.exists()
    assert cli.main(["generate", "no_such_room", "--quick", "--out", str(out)]) == 2
    assert "no_such_room" in capsys.readouterr().err
    assert not out.exists()


def test_the_lock_does_not_make_a_folder_foreign(tmp_path, synthetic_ds):
    """A folder that holds only a released lock is still a new run or dataset folder."""
    from rfmitsuba.core.folder_lock import folder_lock

    out = tmp_path / "run"
    with folder_lock(out, what="train"):
        pass
    assert os.listdir(out) == [".lock"]
    assert cli.main(["train", str(synthetic_ds), "--out", str(out), "--quick", "--model", "splat",
                     "--set", "iterations=5", "--quiet"]) == 0
    assert (out / "final").is_dir()


def test_a_second_predict_is_refused_naming_the_first(other_writer, tmp_path, capsys):
    folder, pid = other_writer
    pos = tmp_path / "p.csv"
    pos.write_text("0 0 1\n")
    assert cli.main(["predict", str(tmp_path / "some_run"), "--positions", str(pos), "--out", str(folder)]) == 2
    err = capsys.readouterr().err
    assert f"pid {pid}" in err and "predict" in err
    assert sorted(p.name for p in folder.iterdir()) == [".lock"]


def test_a_failed_predict_leaves_no_folder(tmp_path, capsys):
    pos = tmp_path / "p.csv"
    pos.write_text("0 0 1\n")
    out = tmp_path / "pred"
    assert cli.main(["predict", str(tmp_path / "no_run"), "--positions", str(pos), "--out", str(out)]) == 2
    assert "no_run" in capsys.readouterr().err
    assert not out.exists()


def test_a_second_experiment_is_refused_naming_the_first(other_writer, synthetic_ds, capsys):
    folder, pid = other_writer
    assert cli.main(["experiment", "parsimony", str(synthetic_ds), "--out", str(folder), "--quick"]) == 2
    err = capsys.readouterr().err
    assert f"pid {pid}" in err and "experiment" in err
    assert sorted(p.name for p in folder.iterdir()) == [".lock"]


def test_a_failed_experiment_leaves_no_folder(tmp_path, capsys):
    out = tmp_path / "exp"
    assert cli.main(["experiment", "parsimony", "--out", str(out)]) == 2
    assert "needs a dataset" in capsys.readouterr().err
    assert not out.exists()


def test_a_second_nerf2like_into_one_folder_is_refused(tmp_path):
    """nerf2like builds its folder beside --out and renames it when complete; while one writer holds
    the folder's lock, a second call is refused naming the first's pid, and nothing is written."""
    import os

    from rfmitsuba.core.errors import RunError
    from rfmitsuba.core.folder_lock import folder_lock
    from rfmitsuba.sim.nerf2like import make_nerf2like

    out = tmp_path / "n2l"
    with folder_lock(tmp_path / ".n2l.writer", what="nerf2like"):
        with pytest.raises(RunError, match=f"another nerf2like into .*n2l.*pid {os.getpid()}"):
            make_nerf2like(out, num_tags=20)
    assert not out.exists() and not list(tmp_path.glob(".n2l.tmp-*"))
