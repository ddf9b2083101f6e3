"""Tests of rfmitsuba.models.members: the ensemble's mean PAS."""
from __future__ import annotations

import numpy as np
import pytest


def test_mean_image_normalises_each_member_per_image_then_averages():
    """Members on different scales weigh alike: each image is min-max normalised first."""
    from rfmitsuba.models.members import mean_image

    rng = np.random.default_rng(0)
    a = rng.uniform(0, 1, (2, 4, 8)).astype(np.float32)
    b = rng.uniform(0, 1, (2, 4, 8)).astype(np.float32)
    norm = [(x - x.min(axis=(1, 2), keepdims=True)) / np.ptp(x, axis=(1, 2), keepdims=True) for x in (a, b)]
    got = mean_image([1e3 * a + 5.0, b])
    np.testing.assert_allclose(got, (norm[0] + norm[1]) / 2, atol=1e-6)
    assert got.dtype == np.float32
    np.testing.assert_allclose(mean_image([a]), norm[0], atol=1e-6)


def test_mean_image_and_field_mean_refuse_bad_members():
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.members import FieldMean, mean_image

    with pytest.raises(ConfigError, match="no members"):
        mean_image([])
    with pytest.raises(ConfigError, match="differ in shape"):
        mean_image([np.zeros((2, 4, 8)), np.zeros((2, 4, 9))])
    with pytest.raises(ConfigError, match="no members"):
        FieldMean([])
