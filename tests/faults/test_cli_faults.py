"""Faults a user can cause end in one named line and an exit code, never a raw traceback
(``rfmitsuba.cli.main``'s handler): Ctrl-C, a full disk, a file where a folder belongs, an
allocation past the machine's memory."""
from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rfmitsuba import cli


def test_generate_asking_for_too_much_memory_names_the_size_and_the_option(tmp_path, capsys):
    out = tmp_path / "big"
    assert cli.main(["generate", "bedroom", "--quick", "--positions", "1000000000", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "out of memory" in err and "GiB" in err and "--positions" in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_out_being_a_file_names_the_path(tmp_path, capsys):
    f = tmp_path / "a_file"
    f.write_text("x")
    assert cli.main(["generate", "bedroom", "--quick", "--out", str(f)]) == 1
    err = capsys.readouterr().err
    assert str(f) in err and "folder" in err and "Traceback" not in err
    assert f.read_text() == "x"


def test_a_full_disk_names_the_path_and_the_cause(tmp_path, capsys, monkeypatch):
    from rfmitsuba.data import nerf2
    from rfmitsuba.eval import invert as inv

    rng = np.random.default_rng(0)
    imgs = inv.channel_images(rng.normal(size=(1, 16)) + 1j * rng.normal(size=(1, 16)), inv.Geometry(920e6, 0.16, 0))
    folder = tmp_path / "f"
    nerf2.write_spectra(folder, imgs)
    nerf2.write_positions(folder / "tx_pos.csv", np.zeros((1, 3)))
    (folder / "gateway_info.yml").write_text("gateway1:\n  position: [1, 0, 0]\n  orientation: [0, 0, 0, 1]\n")

    def full(path, *a, **k):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(np, "save", full)
    out = tmp_path / "o"
    assert cli.main(["invert", str(folder), "--out", str(out), "--scan-images", "1", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "No space left on device" in err and "coefficients.npy" in err and "Traceback" not in err


def test_file_system_errors_name_a_path_and_only_a_way_out_the_command_has():
    """A full disk whose error names no file (a write(2) failing) names the command's --out; a
    read-only folder offers --out only to a command that has one (eval writes into the run)."""
    from rfmitsuba.cli import _named_fault

    full = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    code, msg = _named_fault(full, out="runs/a")
    assert code == 1 and "writing under runs/a: No space left on device; free space or write elsewhere" in msg
    assert "(no path)" in _named_fault(full)[1] and "--out" not in _named_fault(full)[1]
    ro = OSError(errno.EROFS, os.strerror(errno.EROFS), "runs/a/eval")
    assert "write elsewhere (--out)" in _named_fault(ro, out="x")[1]
    msg = _named_fault(ro)[1]
    assert "runs/a/eval: Read-only file system; the folder is read-only: copy it somewhere writable" in msg
    assert "--out" not in msg


def test_an_interrupt_inside_a_drjit_loop_is_named(monkeypatch, capsys):
    def boom(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as e:
            raise RuntimeError("dr.while_loop(): encountered an exception (see above).") from e

    parser = cli.build_parser
    monkeypatch.setattr(cli, "build_parser", lambda: _with_func(parser(), boom))
    assert cli.main(["info"]) == 130
    assert "interrupted; finished work is kept" in capsys.readouterr().err


def test_sigterm_stops_a_command_as_ctrl_c_does(monkeypatch, capsys):
    """kill (SIGTERM) during a command: it unwinds, says finished work is kept, exits 143, and
    the previous SIGTERM handler is back afterwards."""
    def killed(args):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)
        raise AssertionError("SIGTERM did not stop the command")

    before = signal.getsignal(signal.SIGTERM)
    parser = cli.build_parser
    monkeypatch.setattr(cli, "build_parser", lambda: _with_func(parser(), killed))
    assert cli.main(["info"]) == 143
    err = capsys.readouterr().err
    assert "terminated (SIGTERM); finished work is kept" in err and "Traceback" not in err
    assert signal.getsignal(signal.SIGTERM) == before


def _with_func(parser, func):
    for action in parser._subparsers._group_actions:
        for sub in action.choices.values():
            sub.set_defaults(func=func)
    return parser


def test_a_bug_still_raises(monkeypatch):
    def bug(args):
        raise ValueError("a bug, not a user's fault")

    parser = cli.build_parser
    monkeypatch.setattr(cli, "build_parser", lambda: _with_func(parser(), bug))
    with pytest.raises(ValueError):
        cli.main(["info"])


def _terminal_sigint() -> None:
    """In the child: SIGINT as a terminal delivers it. A suite run as a background job (``nohup``,
    ``cmd &``) ignores SIGINT, its children inherit that, and Python then never raises
    KeyboardInterrupt: the interrupt would be lost before rfmitsuba sees it."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.slow
def test_ctrl_c_during_generate_exits_130_and_keeps_finished_work(tmp_path):
    out = tmp_path / "ds"
    env = dict(os.environ, RFMITSUBA_QUIET="1")
    exe = Path(sys.executable).parent / "rfmitsuba"       # the installed console script
    proc = subprocess.Popen([str(exe), "generate", "bedroom", "--task", "rx",
                             "--quick", "--person-positions", "40", "--out", str(out)], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                            env=env, text=True, preexec_fn=_terminal_sigint)
    t0 = time.time()
    def chunks():
        return list((out / "chunks").glob("*/chunk.json"))

    while not chunks() and proc.poll() is None and time.time() - t0 < 240:
        time.sleep(0.05)                              # 41 states take about 25 s: stop after the first
    assert proc.poll() is None, "generate ended before it could be interrupted"
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=240)
    assert proc.returncode == 130, err
    assert "interrupted; finished work is kept" in err and "Traceback" not in err
    assert (out / "meta.json").exists() and chunks()
    from rfmitsuba.data.store import Dataset

    Dataset(out, check=False)                         # what was written opens (it resumes on the next call)


@pytest.mark.parametrize("seeds, bad", [("0,x", "'x'"), ("0,,1", "''"), ("1.5", "'1.5'"), ("-1", "'-1'")])
def test_compare_names_the_seed_that_is_not_one(tmp_path, capsys, seeds, bad):
    assert cli.main(["compare", str(tmp_path / "ds"), "--out", str(tmp_path / "o"), "--seeds", seeds]) == 2
    err = capsys.readouterr().err
    assert "--seeds" in err and bad in err
    assert not (tmp_path / "o").exists()


def test_a_run_without_validation_positions_says_why(synthetic_ds, tmp_path, capsys):
    out = tmp_path / "run"
    args = ["train", str(synthetic_ds), "--out", str(out), "--model", "splat", "--quiet", "--set", "val_fraction=0"]
    for s in ["iterations=5", "downsample=5", "splat.init=\"random\"", "splat.num_gaussians=30", "splat.net.width=8"]:
        args += ["--set", s]
    assert cli.main(args) == 0
    printed = capsys.readouterr().out
    assert "no validation SSIM" in printed and "val_fraction" in printed and "nan" not in printed
    import json

    def no_nan(token):
        raise AssertionError(f"summary.json holds {token}, which is not standard JSON")

    s = json.loads((out / "final" / "summary.json").read_text(), parse_constant=no_nan)
    assert s["val_ssim"] is None and s["best_val_ssim"] is None


def test_auto_without_validation_positions_says_how_it_chose(synthetic_ds, tmp_path):
    """No position held back: the trials cannot be compared, and choice.json says the choice
    was the order of preference, not a validation score."""
    import json

    out = tmp_path / "run"
    args = ["train", str(synthetic_ds), "--out", str(out), "--quiet", "--set", "val_fraction=0"]
    for s in ["iterations=200", "downsample=5", "splat.init=\"random\"", "splat.num_gaussians=30", "splat.net.width=8",
              "coherent_gaussians.scatterers=4"]:
        args += ["--set", s]
    assert cli.main(args) == 0
    choice = json.loads((out / "select" / "choice.json").read_text())
    assert "no validation positions" in choice["rule"]
    assert choice["chosen"] == next(iter(choice["trials"]))         # trials are recorded in the order of preference
    assert all(t["best_val_ssim"] is None for t in choice["trials"].values())


@pytest.mark.parametrize("batch", ["-1", "0", "x"])
def test_a_batch_that_is_not_a_count_is_refused(tmp_path, capsys, batch):
    """``--batch -1`` once rendered nothing and overwrote the evaluation; 0 crashed in range()."""
    for cmd in (["eval", str(tmp_path / "run")], ["predict", str(tmp_path / "run"), "--positions", "p.txt",
                                                  "--out", str(tmp_path / "o")]):
        with pytest.raises(SystemExit) as e:
            cli.main(cmd + ["--batch", batch])
        assert e.value.code == 2
        assert f"--batch: {batch!r} is not a whole number >= 1" in capsys.readouterr().err


@pytest.mark.parametrize("counts, bad", [("8,abc", "'abc'"), ("0,20", "'0'"), ("20,-5", "'-5'")])
def test_experiment_names_the_count_that_is_not_one(tmp_path, capsys, counts, bad):
    assert cli.main(["experiment", "motivation", str(tmp_path / "ds"), "--out", str(tmp_path / "o"),
                     "--counts", counts]) == 2
    err = capsys.readouterr().err
    assert f"--counts: {bad} is not a whole number >= 1" in err and "Traceback" not in err


def test_nerf2like_refuses_more_tags_than_memory_holds_at_once(tmp_path, capsys):
    """A billion tags: refused before minutes of trajectory work, naming the size and --tags."""
    assert cli.main(["nerf2like", "--out", str(tmp_path / "n"), "--tags", "1000000000", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "GiB" in err and "(--tags)" in err and "Traceback" not in err
    assert not (tmp_path / "n").exists()
