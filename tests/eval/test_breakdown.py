"""Tests of rfmitsuba.eval.breakdown: SSIM binned by the distance to the fixed device and to the
nearest training position."""
from __future__ import annotations

import numpy as np
import pytest

from rfmitsuba.core.errors import ImageError
from rfmitsuba.eval.breakdown import breakdown, by_distance, fixed_device


def test_by_distance_quartiles_by_hand():
    d = np.arange(8.0)                    # quartile edges 0, 1.75, 3.5, 5.25, 7
    s = np.array([0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2])
    out = by_distance(d, {"model": s, "nn": 1 - s})
    assert out["edges"] == [0.0, 1.75, 3.5, 5.25, 7.0]
    assert out["count"] == [2, 2, 2, 2]
    np.testing.assert_allclose(out["model"], [0.85, 0.65, 0.45, 0.25])
    np.testing.assert_allclose(out["nn"], [0.15, 0.35, 0.55, 0.75])


def test_by_distance_keeps_every_image_once_and_the_overall_mean():
    rng = np.random.default_rng(3)
    d = rng.exponential(2.0, 101)
    s = rng.uniform(0, 1, 101)
    out = by_distance(d, {"model": s}, bins=5)
    assert sum(out["count"]) == 101
    assert np.average(out["model"], weights=out["count"]) == pytest.approx(s.mean())
    assert out["edges"][0] == d.min() and out["edges"][-1] == d.max()


def test_by_distance_equal_distances_make_one_bin():
    out = by_distance(np.full(5, 2.0), {"model": np.arange(5.0)})
    assert out["edges"] == [2.0, 2.0] and out["count"] == [5] and out["model"] == [2.0]


@pytest.mark.parametrize("d, s, match", [
    (np.arange(3.0), np.arange(4.0), "series 'model'"),
    (np.array([0.0, np.nan]), np.zeros(2), "non-finite"),
    (np.zeros(0), np.zeros(0), "no test images"),
])
def test_by_distance_names_bad_input(d, s, match):
    with pytest.raises(ImageError, match=match):
        by_distance(d, {"model": s})


def test_breakdown_distances():
    train = np.array([[0.0, 0, 0], [10.0, 0, 0]])
    test = np.array([[1.0, 0, 0], [2.0, 0, 0], [7.0, 0, 0], [9.5, 0, 0]])
    s = np.array([0.9, 0.8, 0.4, 0.6])
    out = breakdown(test, train, np.array([0.0, 0.0, 0.0]), {"model": s}, bins=2)
    # to the fixed device: 1, 2 | 7, 9.5 (median 4.5)
    assert out["to_fixed_device"]["edges"] == [1.0, 4.5, 9.5]
    np.testing.assert_allclose(out["to_fixed_device"]["model"], [0.85, 0.5])
    # to the nearest training position: 1, 2, 3, 0.5 -> 0.5, 1 | 2, 3 (median 1.5)
    assert out["to_nearest_training"]["edges"] == [0.5, 1.5, 3.0]
    np.testing.assert_allclose(out["to_nearest_training"]["model"], [0.75, 0.6])
    assert breakdown(test, train, None, {"model": s})["to_fixed_device"] is None


class _Data:
    def __init__(self, task, source, view_pos):
        self.task, self.transmitter, self.view_pos = task, source, view_pos


def test_fixed_device_by_task():
    view = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0]])
    np.testing.assert_allclose(fixed_device(_Data("tx", None, view)), [1, 2, 3])
    np.testing.assert_allclose(fixed_device(_Data("rx", np.array([0.3, 0.3, 2.0]), view)), [0.3, 0.3, 2.0])
    assert fixed_device(_Data("rx", None, view)) is None
