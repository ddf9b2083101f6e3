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
                             "--quick", "--human-positions", "40", "--out", str(out)], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
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
    for s in ["iterations=5", "downsample=5", "field.init=\"random\"", "field.num_gaussians=30", "field.net.width=8"]:
        args += ["--set", s]
    assert cli.main(args) == 0
    printed = capsys.readouterr().out
    assert "no validation SSIM" in printed and "val_fraction" in printed and "nan" not in printed
