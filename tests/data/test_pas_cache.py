"""rfmitsuba.data.pas_cache: a dataset state's training images made once, bit-identical, kept beside it."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest


@pytest.fixture
def own_ds(synthetic_ds, tmp_path):
    """A copy of the synthetic dataset without a cache, for tests that change or count it."""
    out = tmp_path / "ds"
    shutil.copytree(synthetic_ds, out, ignore=shutil.ignore_patterns("cache"))
    return out


def _computed(d, idx, block):
    from rfmitsuba.data.views import downsample
    from rfmitsuba.rf.bartlett_ref import normalize

    return normalize(downsample(d.raw(idx), block))


@pytest.mark.parametrize("block", [2, 3])
def test_cached_images_are_the_computed_ones_and_are_read_from_disk(own_ds, monkeypatch, block):
    """Block means read through the cache equal the computed ones bit for bit, in any sample order;
    a second reader reads the files (the raw PAS are never opened) and gets the same arrays."""
    from rfmitsuba.data import pas_cache
    from rfmitsuba.data.samples import SampleData

    d = SampleData.open_samples(own_ds, states="all")
    idx = np.concatenate([d.train[::-3], d.test[:5]])
    np.testing.assert_array_equal(d.pas(idx, d=block), _computed(d, idx, block))
    npy, meta = pas_cache.entry_paths(own_ds, int(d.states[idx[0]]), block)
    assert npy.is_file() and json.loads(meta.read_text())["d"] == block
    again = SampleData.open_samples(own_ds, states="all")

    def no_raw(state):
        raise AssertionError("the raw PAS were read")
    monkeypatch.setattr(again._ds, "pas", no_raw)
    np.testing.assert_array_equal(again.pas(idx, d=block), d.pas(idx, d=block))


def test_a_regenerated_state_or_a_damaged_entry_is_made_again(own_ds, monkeypatch):
    """An entry whose chunk.json changed (a regenerated state) or whose file is damaged is computed
    again; an intact one is not."""
    from rfmitsuba.data import pas_cache
    from rfmitsuba.data.samples import SampleData
    from rfmitsuba.data.store import chunk_name

    d = SampleData.open_samples(own_ds, states="all")
    idx = d.train[:12]
    first = d.pas(idx, d=2)
    made = []
    real = pas_cache._make
    monkeypatch.setattr(pas_cache, "_make", lambda ds, s, dd: made.append(s) or real(ds, s, dd))
    d.pas(idx, d=2)
    assert made == []
    s = int(d.states[idx[0]])
    chunk_json = own_ds / "chunks" / chunk_name(s) / "chunk.json"
    chunk_json.write_text(chunk_json.read_text() + " ")
    np.testing.assert_array_equal(d.pas(idx, d=2), first)
    assert made == [s]
    npy, _ = pas_cache.entry_paths(own_ds, s, 2)
    npy.write_bytes(b"not an array")
    np.testing.assert_array_equal(d.pas(idx, d=2), first)
    assert made == [s, s]


def test_a_folder_that_cannot_be_written_is_read_without_a_cache(own_ds, monkeypatch):
    from rfmitsuba.data import pas_cache
    from rfmitsuba.data.samples import SampleData

    def refuse(*a, **k):
        raise PermissionError("read-only")
    monkeypatch.setattr(pas_cache.np, "save", refuse)
    d = SampleData.open_samples(own_ds, states="all")
    idx = d.train[:9]
    np.testing.assert_array_equal(d.pas(idx, d=2), _computed(d, idx, 2))
    assert not list((own_ds / "cache").rglob("*.npy"))


def test_a_non_finite_pas_is_named_when_asked_for_and_only_then(own_ds, monkeypatch):
    """A NaN in one raw PAS is cached as such: reading other samples of its state works, reading it
    raises the DatasetError that names its antenna position and state, as without a cache."""
    from rfmitsuba.core.errors import DatasetError
    from rfmitsuba.data.samples import SampleData

    d = SampleData.open_samples(own_ds, states="all")
    k = int(d.train[3])
    s, a = int(d.states[k]), int(d.antennas[k])
    real = d._ds.pas

    def with_nan(state):
        x = np.array(real(state))
        if state == s:
            x[a, 2, 5] = np.nan
        return x
    monkeypatch.setattr(d._ds, "pas", with_nan)
    others = d.train[(d.states[d.train] == s) & (d.antennas[d.train] != a)][:4]
    assert d.pas(others, d=2).shape == (len(others), 45, 180)
    with pytest.raises(DatasetError, match=f"antenna position {a} \\(state {s}\\) contains NaN"):
        d.pas(np.concatenate([others, [k]]), d=2)


def test_a_nerf2_folder_is_read_without_a_cache(synthetic_ds, tmp_path):
    """A NeRF2 spectrum folder has no chunks to key an entry by: its block means are computed, and
    nothing is written into it."""
    from rfmitsuba.data import nerf2
    from rfmitsuba.data.samples import SampleData
    from rfmitsuba.data.store import Dataset

    folder = nerf2.write(Dataset(synthetic_ds), tmp_path / "n", state=0)
    d = SampleData.open_samples(folder, states="empty")
    idx = d.train[:6]
    np.testing.assert_array_equal(d.pas(idx, d=2), _computed(d, idx, 2))
    assert not (folder / "cache").exists()
