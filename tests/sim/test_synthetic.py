"""Synthetic dynamic datasets: valid format, and the person changes the PAS."""
from __future__ import annotations

import numpy as np
import pytest


def test_person_perturbs_the_pas(synthetic_ds):
    from rfmitsuba.core.ssim import ssim_images
    from rfmitsuba.data.store import open_dataset
    from rfmitsuba.rf.bartlett_ref import normalize as minmax

    ds = open_dataset(synthetic_ds)
    assert ds.num_states == 7 and ds.num_antennas == 30
    empty, person = minmax(np.asarray(ds.pas(0))), minmax(np.asarray(ds.pas(3)))
    s = ssim_images(person, empty)
    assert 0.3 < s.mean() < 0.99  # a visible but not overwhelming perturbation


def test_bad_sizes(tmp_path):
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.sim import synthetic

    with pytest.raises(ConfigError, match="antennas"):
        synthetic.make_dataset(tmp_path / "x", antennas=2, people=3)
