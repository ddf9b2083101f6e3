"""Flat (state, antenna) sample views: splits keep test antennas and people out, noise, features."""
from __future__ import annotations

import numpy as np
import pytest

from rfmitsuba.core.errors import ConfigError


def test_splits_hold_out_test_antennas_and_persons(synthetic_ds):
    from rfmitsuba.data.samples import SampleData

    d = SampleData.open_samples(synthetic_ds, states="all")
    sp = d.split
    tr_a, tr_s = d.antennas[d.train], d.states[d.train]
    assert not np.isin(tr_a, sp.antenna_test).any()
    assert not np.isin(tr_s, np.asarray(sp.person_test) + 1).any()
    assert (tr_s == 0).any() and (tr_s > 0).any()
    te = d.test
    assert np.isin(d.antennas[te], sp.antenna_test).all() and np.isin(d.states[te], np.asarray(sp.person_test) + 1).all()
    # SPEC: ~19% of the person positions held out
    assert len(sp.person_test) == 1 and len(sp.person_train) == 5


def test_state_sets_duplicate_and_subset(synthetic_ds):
    from rfmitsuba.data.samples import SampleData

    e = SampleData.open_samples(synthetic_ds, states="empty")
    assert (e.states == 0).all() and len(e.train) == 24
    dup = SampleData.open_samples(synthetic_ds, states="empty", duplicate=3)
    assert len(dup.train) == 3 * len(e.train)
    assert np.array_equal(dup.pas(dup.train[:2]), e.pas(e.train[:2]))
    sub = SampleData.open_samples(synthetic_ds, states="all", train_antennas=10)
    assert len(np.unique(sub.antennas[sub.train])) == 10
    with pytest.raises(ConfigError, match="states"):
        SampleData.open_samples(synthetic_ds, states="some")


def test_noise_only_on_training_samples(synthetic_ds):
    from rfmitsuba.data.samples import SampleData

    clean = SampleData.open_samples(synthetic_ds, states="all")
    noisy = SampleData.open_samples(synthetic_ds, states="all", noise_snr_db=0.0, noise_seed=1)
    assert not np.allclose(noisy.raw(noisy.train[:3]), clean.raw(clean.train[:3]))
    assert np.array_equal(noisy.raw(noisy.test[:3]), clean.raw(clean.test[:3]))
    again = SampleData.open_samples(synthetic_ds, states="all", noise_snr_db=0.0, noise_seed=1)
    assert np.array_equal(again.raw(again.train[:3]), noisy.raw(noisy.train[:3]))


def test_noisy_training_samples_are_not_read_from_the_clean_pas(synthetic_ds, monkeypatch):
    """With noise, a training sample's PAS is made apart (from its channels, or here, a dataset
    without channels, from its PAS once): no PAS of a mixed batch is read twice, and its test
    rows are the clean ones."""
    from rfmitsuba.data.samples import SampleData

    noisy = SampleData.open_samples(synthetic_ds, states="all", noise_snr_db=5.0, noise_seed=3)
    clean = SampleData.open_samples(synthetic_ds, states="all")
    idx = np.concatenate([noisy.train[:5], noisy.test[:4], noisy.train[5:7]])
    read = []
    real = noisy._ds.pas

    def counted(state):
        store = real(state)

        class Rows:
            def __getitem__(self, rows):
                read.extend((state, int(a)) for a in np.atleast_1d(rows))
                return store[rows]
        return Rows()

    monkeypatch.setattr(noisy._ds, "pas", counted)
    out = noisy.raw(idx)
    assert len(read) == len(set(read)) == len(idx)
    assert {(int(noisy.states[k]), int(noisy.antennas[k])) for k in noisy.test[:4]} <= set(read)
    np.testing.assert_array_equal(out[5:9], clean.raw(noisy.test[:4]))
    assert not np.allclose(out[:5], clean.raw(noisy.train[:5]))


def test_noise_does_not_depend_on_the_batch(synthetic_ds):
    """Noisy PAS are made a state at a time; each sample's noise is its own, however it is asked for."""
    from rfmitsuba.data.samples import SampleData

    together = SampleData.open_samples(synthetic_ds, states="all", noise_snr_db=5.0, noise_seed=2)
    alone = SampleData.open_samples(synthetic_ds, states="all", noise_snr_db=5.0, noise_seed=2)
    idx = together.train[:12]
    batch = together.raw(idx)
    single = np.stack([alone.raw(idx[i:i + 1])[0] for i in range(len(idx))[::-1]])[::-1]
    np.testing.assert_array_equal(batch, single)    # to the bit: a job's samples must not depend on its history


def test_noise_level():
    from rfmitsuba.data.samples import add_noise_channels

    rng = np.random.default_rng(0)
    h = np.exp(1j * rng.uniform(0, 6.28, (2000, 16)))  # unit power per element
    n = add_noise_channels(h, 10.0, rng=rng) - h
    assert abs(np.mean(np.abs(n) ** 2) - 0.1) < 0.005  # 10 dB below unit power


def test_person_features():
    from rfmitsuba.data.samples import person_features, num_person_features

    box = np.array([[0, 0, 0], [4, 4, 4]], float)
    f = person_features(np.array([[np.nan] * 3, [2.0, 2.0, 0.0]]), box, octaves=2)
    assert f.shape == (2, num_person_features(2))
    assert (f[0] == 0).all() and f[1, -1] == 1.0
    assert np.allclose(f[1, :3], [0.25, 0.25, 0.0])


def test_pas_in_chunks_is_the_pas_at_once_and_names_a_bad_sample(synthetic_ds, monkeypatch):
    """views.normalised_pas reads, checks, block-averages and normalises views.PAS_CHUNK samples at a
    time (a walk dataset's training samples are 2.6 GB at 90 x 360): with chunks of 7 the result
    equals the normalised block means of all raw PAS at once, and through SampleData.pas (full
    resolution; block means come from the dataset's cache, tests/data/test_pas_cache.py) a NaN in a
    later chunk names its own antenna position and state."""
    from rfmitsuba.core.errors import DatasetError
    from rfmitsuba.data import views
    from rfmitsuba.data.samples import SampleData
    from rfmitsuba.data.views import downsample
    from rfmitsuba.rf.bartlett_ref import normalize

    d = SampleData.open_samples(synthetic_ds, states="all")
    idx = d.train[::-1][:40]
    whole = normalize(downsample(d.raw(idx), 2))
    monkeypatch.setattr(views, "PAS_CHUNK", 7)
    np.testing.assert_array_equal(views.normalised_pas(idx, d.raw, d=2, bad=str), whole)
    np.testing.assert_array_equal(d.pas(idx, d=1), normalize(d.raw(idx)))
    assert d.pas(idx[:0], d=3).shape == (0, 30, 120)
    raw = d.raw
    k = int(idx[30])
    monkeypatch.setattr(d, "raw", lambda part: np.where(np.asarray(part)[:, None, None] == k, np.nan, raw(part)))
    with pytest.raises(DatasetError, match=f"antenna position {int(d.antennas[k])} \\(state {int(d.states[k])}\\)"):
        d.pas(idx, d=1)


def test_downsample_is_the_block_mean():
    from rfmitsuba.data.views import downsample

    x = np.random.default_rng(0).random((3, 90, 360)).astype(np.float32)
    for d in (1, 2, 3, 5):
        ref = x.reshape(3, 90 // d, d, 360 // d, d).astype(np.float64).mean(axis=(2, 4))
        np.testing.assert_allclose(downsample(x, d), ref, atol=1e-6)
        assert downsample(x, d).dtype == np.float32


def test_grid_layout_and_the_first_walk_frames(synthetic_ds):
    """A grid layout keeps its count, spread over the floor and the same for every subset seed;
    walk_frames trains on the first walk positions only and keeps the test ones out."""
    from rfmitsuba.data.layout import grid_layout
    from rfmitsuba.data.samples import SampleData

    grid = SampleData.open_samples(synthetic_ds, states="empty", train_antennas=8, layout="grid")
    again = SampleData.open_samples(synthetic_ds, states="empty", train_antennas=8, layout="grid", subset_seed=5)
    chosen = np.unique(grid.antennas[grid.train])
    assert len(chosen) == 8 and np.array_equal(chosen, np.unique(again.antennas[again.train]))
    assert np.array_equal(grid.test, SampleData.open_samples(synthetic_ds, states="empty").test)
    d = SampleData.open_samples(synthetic_ds, states="person", walk_frames=3)
    sp = d.split
    assert set(d.states[d.train]) == {int(h) + 1 for h in sp.person_train if h < 3}
    assert np.array_equal(d.test, SampleData.open_samples(synthetic_ds, states="person").test)
    none = SampleData.open_samples(synthetic_ds, states="all", walk_frames=0)
    assert (none.states[none.train] == 0).all()
    with pytest.raises(ConfigError, match="layout"):
        SampleData.open_samples(synthetic_ds, states="all", train_antennas=8, layout="spiral")
    # the grid: a 10 x 10 lattice thinned to 4 keeps one position near each quarter's middle
    xy = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0)), -1).reshape(-1, 2)
    pos = np.c_[xy, np.ones(len(xy))]
    idx = grid_layout(pos, 4)
    assert len(idx) == 4 and np.array_equal(idx, np.sort(idx))
    quarters = {(int(x >= 5), int(y >= 5)) for x, y in xy[idx]}
    assert len(quarters) == 4
    assert np.array_equal(grid_layout(pos, 200), np.arange(100))
