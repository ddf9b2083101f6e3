"""rfmitsuba.core.folder_lock: one writer per output folder; a dead holder leaves no lock."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from rfmitsuba.core.errors import RunError
from rfmitsuba.core.folder_lock import LOCK_NAME, folder_lock


def test_second_holder_is_refused_naming_the_first(tmp_path):
    with folder_lock(tmp_path / "out", what="reproduce"):
        with pytest.raises(RunError, match=rf"another reproduce is writing into .*out \(pid {os.getpid()} on "):
            with folder_lock(tmp_path / "out", what="reproduce"):
                pass
    with folder_lock(tmp_path / "out", what="reproduce"):  # released on leaving the block
        pass
    assert (tmp_path / "out" / LOCK_NAME).is_file()


def test_a_killed_holder_leaves_no_lock(tmp_path):
    code = ("import os, sys; from rfmitsuba.core.folder_lock import folder_lock\n"
            f"with folder_lock({str(tmp_path)!r}, what='compare'):\n    os._exit(3)\n")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 3   # died holding it
    with folder_lock(tmp_path, what="compare"):
        pass


def test_reproduce_and_compare_take_it(tmp_path):
    from rfmitsuba.experiments.compare import compare
    from rfmitsuba.experiments.reproduce import reproduce
    from rfmitsuba.experiments.sizes import size_config

    with folder_lock(tmp_path / "r", what="reproduce"):
        with pytest.raises(RunError, match="another reproduce is writing into"):
            reproduce(tmp_path / "r", size_config("tiny"), quiet=True)
    assert [p.name for p in (tmp_path / "r").iterdir()] == [LOCK_NAME]  # nothing else written
    with folder_lock(tmp_path / "c", what="compare"):
        with pytest.raises(RunError, match="another compare is writing into"):
            compare(tmp_path / "no_dataset", tmp_path / "c")
