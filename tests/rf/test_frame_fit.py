"""Line-of-sight fit of the array frame (rfmitsuba.rf.frame_fit): it recovers a wrongly stated
frame from spectra alone, leaves a right one alone, and names bad input."""
from __future__ import annotations

import numpy as np
import pytest

from los_data import F, los_spectra


def _los_data(true_to_world: np.ndarray, *, n: int = 40, seed: int = 0):
    return los_spectra(true_to_world=true_to_world, n=n, seed=seed)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(a.T @ b) - 1) / 2, -1, 1))))


def test_rotation_matrix():
    from rfmitsuba.rf.frame_fit import rotation_matrix

    np.testing.assert_allclose(rotation_matrix([0, 0, np.pi / 2]) @ [1.0, 0, 0], [0, 1.0, 0], atol=1e-12)
    np.testing.assert_allclose(rotation_matrix(np.zeros(3)), np.eye(3))
    r = rotation_matrix([0.3, -0.2, 0.5])
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)


def test_a_wrongly_stated_frame_is_recovered():
    """Stated 30 degrees off the array's true frame: the fit lands within 2 degrees of the truth
    and gains clearly in correlation."""
    from rfmitsuba.rf.frame_fit import los_frame_fit, rotation_matrix

    pas, x, y = _los_data(np.eye(3))
    stated = rotation_matrix(np.radians(30) * np.array([0.6, 0.7, 0.39]) / np.linalg.norm([0.6, 0.7, 0.39]))
    fit = los_frame_fit(pas, x, y, rx_to_world=stated, frequency_hz=F, candidates=200)
    assert _angle_deg(fit.rx_to_world(stated), np.eye(3)) < 2.0
    assert fit.gain > 0.05 and fit.score > 0.99
    assert 25 < fit.angle_deg < 35


def test_a_right_frame_is_left_alone():
    from rfmitsuba.rf.frame_fit import los_frame_fit, rotation_matrix

    true = rotation_matrix([0.0, 0.0, 0.4])      # a rotated gateway, stated correctly
    pas, x, y = _los_data(true, seed=1)
    fit = los_frame_fit(pas, x, y, rx_to_world=true, frequency_hz=F, candidates=100)
    assert fit.gain < 1e-3 and fit.stated_score > 0.99
    assert _angle_deg(fit.rx_to_world(true), true) < 2.0


def test_bad_input_is_named():
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.rf.frame_fit import los_frame_fit

    pas, x, y = _los_data(np.eye(3), n=4)
    with pytest.raises(ConfigError, match="x, y"):
        los_frame_fit(pas, x[:3], y, rx_to_world=None, frequency_hz=F)
    bad = pas.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ConfigError, match="finite"):
        los_frame_fit(bad, x, y, rx_to_world=None, frequency_hz=F)
    with pytest.raises(ConfigError, match="array centre"):
        los_frame_fit(pas, x, x, rx_to_world=None, frequency_hz=F)
