"""A chunk overwritten in place (its size unchanged) is found: ``generate`` names it on resume and
``--repair`` re-simulates it; ``train`` and ``eval`` refuse it, naming the chunk and the way out."""
from __future__ import annotations

import shutil

import numpy as np

from rfmitsuba import cli


def _corrupt(ds_root, state=0):
    f = ds_root / "chunks" / f"{state:05d}" / "pas.npy"
    size = f.stat().st_size
    with open(f, "r+b") as fh:                     # 256 bytes of the data overwritten by 3.4e38
        fh.seek(size - 4096)
        fh.write(np.full(64, 3.4e38, np.float32).tobytes())
    assert f.stat().st_size == size
    return f


def test_a_chunk_corrupted_in_place_is_found_and_repaired(quick_dataset, tmp_path, capsys):
    root = tmp_path / "ds"
    shutil.copytree(quick_dataset.path, root)
    before = np.load(root / "chunks" / "00000" / "pas.npy").copy()
    _corrupt(root)
    run = tmp_path / "run"
    assert cli.main(["train", str(root), "--out", str(run), "--quick", "--model", "splat", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "00000" in err and "sha256" in err and "--repair" in err
    assert not run.exists()
    gen = ["generate", "bedroom", "--task", "rx", "--quick", "--out", str(root)]
    assert cli.main(gen) == 2
    err = capsys.readouterr().err
    assert "00000" in err and "--repair" in err
    assert cli.main(gen + ["--repair"]) == 0
    capsys.readouterr()
    np.testing.assert_array_equal(np.load(root / "chunks" / "00000" / "pas.npy"), before)
    from rfmitsuba.data.store import open_dataset

    assert open_dataset(root).verify() == []
