"""Flat (state, antenna) sample views: splits keep test antennas and humans out, noise, features."""
from __future__ import annotations

import numpy as np
import pytest

from rfmitsuba.core.errors import ConfigError


def test_splits_hold_out_test_antennas_and_humans(synthetic_ds):
    from rfmitsuba.data.samples import SampleData

    d = SampleData.open_samples(synthetic_ds, states="all")
    sp = d.split
    tr_a, tr_s = d.antennas[d.train], d.states[d.train]
    assert not np.isin(tr_a, sp.antenna_test).any()
    assert not np.isin(tr_s, np.asarray(sp.human_test) + 1).any()
    assert (tr_s == 0).any() and (tr_s > 0).any()
    te = d.test
    assert np.isin(d.antennas[te], sp.antenna_test).all() and np.isin(d.states[te], np.asarray(sp.human_test) + 1).all()
    # SPEC: ~19% of the human positions held out
    assert len(sp.human_test) == 1 and len(sp.human_train) == 5


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


def test_noise_does_not_depend_on_the_batch(synthetic_ds):
    """Noisy PAS are made a state at a time; each sample's noise is its own, however it is asked for."""
    from rfmitsuba.data.samples import SampleData

    together = SampleData.open_samples(synthetic_ds, states="all", noise_snr_db=5.0, noise_seed=2)
    alone = SampleData.open_samples(synthetic_ds, states="all", noise_snr_db=5.0, noise_seed=2)
    idx = together.train[:12]
    batch = together.raw(idx)
    single = np.stack([alone.raw(idx[i:i + 1])[0] for i in range(len(idx))[::-1]])[::-1]
    np.testing.assert_allclose(batch, single, rtol=1e-5, atol=1e-7 * float(np.abs(batch).max()))


def test_noise_level():
    from rfmitsuba.data.samples import add_noise_channels

    rng = np.random.default_rng(0)
    h = np.exp(1j * rng.uniform(0, 6.28, (2000, 16)))  # unit power per element
    n = add_noise_channels(h, 10.0, rng=rng) - h
    assert abs(np.mean(np.abs(n) ** 2) - 0.1) < 0.005  # 10 dB below unit power


def test_human_features():
    from rfmitsuba.data.samples import human_features, num_human_features

    box = np.array([[0, 0, 0], [4, 4, 4]], float)
    f = human_features(np.array([[np.nan] * 3, [2.0, 2.0, 0.0]]), box, octaves=2)
    assert f.shape == (2, num_human_features(2))
    assert (f[0] == 0).all() and f[1, -1] == 1.0
    assert np.allclose(f[1, :3], [0.25, 0.25, 0.0])
