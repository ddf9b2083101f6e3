"""Line-of-sight fit of the array's per-element phase offsets (rfmitsuba.rf.calibration_fit): it
recovers offsets anywhere in +-180 degrees from spectra alone, leaves an array without offsets
alone, and names bad input."""
from __future__ import annotations

import numpy as np
import pytest

from los_data import F, los_spectra


def los_data_with_offsets(offsets_rad: np.ndarray, *, n: int = 32, seed: int = 0):
    return los_spectra(offsets_rad=offsets_rad, n=n, seed=seed)


def _wrapped_deg(a: np.ndarray) -> np.ndarray:
    return np.abs(np.degrees(np.angle(np.exp(1j * a))))


def _beyond_a_ramp_deg(diff: np.ndarray) -> np.ndarray:
    """|diff| [degrees] per element after the best common phase and linear ramp across the 4x4
    grid are taken out: a ramp only tilts the beam by a degree or two, which line-of-sight
    spectra of tags in a small patch barely see (the field's learned pose takes it)."""
    p, q = np.divmod(np.arange(16), 4)
    steps = np.radians(np.arange(-60.0, 60.5, 1.0))
    z = np.exp(1j * (diff[None, None] - steps[:, None, None] * q - steps[None, :, None, None][..., 0] * p))
    total = z.sum(-1)
    i, j = np.unravel_index(int(np.argmax(np.abs(total))), total.shape)
    return _wrapped_deg(np.angle(z[i, j] * np.conj(total[i, j])))


@pytest.mark.parametrize("seed", [3, 7])
def test_offsets_anywhere_in_180_degrees_are_recovered(seed):
    """Offsets uniform in +-180 degrees: with none assumed the line of sight correlates with the
    spectra at under 0.5; the fit draws them at correlation > 0.99 and finds every element's
    offset within 8 degrees up to a common phase and a linear ramp (a beam tilt), or its twin's
    (conj, both axes reversed: the same spectra; seed 7 finds the twin)."""
    from rfmitsuba.rf.calibration_fit import los_calibration_fit

    true = np.random.default_rng(seed).uniform(-np.pi, np.pi, 16)
    pas, x, y = los_data_with_offsets(true)
    fit = los_calibration_fit(pas, x, y, rx_to_world=None, frequency_hz=F)
    assert fit.stated_score < 0.5 and fit.score > 0.99 and fit.gain > 0.5
    assert fit.phase_rad[0] == 0.0
    twin = -true[::-1]
    assert min(_beyond_a_ramp_deg(fit.phase_rad - t).max() for t in (true, twin)) < 8.0
    np.testing.assert_allclose(np.abs(fit.cal), 1.0)


def test_a_fit_and_its_twin_draw_the_same_spectra():
    """Offsets within +-60 degrees: the fit lands on the truth or on its twin (conj, both axes
    reversed), up to a ramp; both draw the line of sight alike (the ambiguity the module
    docstring names)."""
    from rfmitsuba.rf.calibration_fit import los_calibration_fit

    true = np.random.default_rng(11).uniform(-np.pi / 3, np.pi / 3, 16)
    pas, x, y = los_data_with_offsets(true, seed=2)
    fit = los_calibration_fit(pas, x, y, rx_to_world=None, frequency_hz=F)
    assert fit.score > 0.99
    assert min(_beyond_a_ramp_deg(fit.phase_rad - t).max() for t in (true, -true[::-1])) < 8.0
    twin_pas, _, _ = los_data_with_offsets(-true[::-1], seed=2)
    for a, b in zip(pas, twin_pas):
        assert np.corrcoef(a.ravel(), b.ravel())[0, 1] > 0.9999
    # the fit hands back the other twin too: its reflection, re-referenced, with the same score
    expect = np.angle(np.exp(1j * (-fit.phase_rad[::-1] + fit.phase_rad[-1])))
    np.testing.assert_allclose(np.angle(np.exp(1j * (fit.twin_phase_rad - expect))), 0.0, atol=1e-9)
    assert fit.twin_phase_rad[0] == 0.0 and abs(fit.twin_score - fit.score) < 1e-3
    # of the two, the fit keeps the one nearer no offset
    assert abs(fit.cal.sum()) >= abs(fit.twin_cal.sum()) - 1e-9


def test_an_array_without_offsets_is_left_alone():
    from rfmitsuba.rf.calibration_fit import los_calibration_fit

    pas, x, y = los_data_with_offsets(np.zeros(16), seed=1)
    fit = los_calibration_fit(pas, x, y, rx_to_world=None, frequency_hz=F, restarts=1, hops=4)
    assert fit.stated_score > 0.99 and fit.gain < 1e-3
    assert _wrapped_deg(fit.phase_rad).max() < 6.0


def test_bad_input_is_named():
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.rf.calibration_fit import los_calibration_fit

    pas, x, y = los_data_with_offsets(np.zeros(16), n=4)
    with pytest.raises(ConfigError, match="x, y"):
        los_calibration_fit(pas, x[:3], y, rx_to_world=None, frequency_hz=F)
    bad = pas.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ConfigError, match="finite"):
        los_calibration_fit(bad, x, y, rx_to_world=None, frequency_hz=F)
    with pytest.raises(ConfigError, match="array centre"):
        los_calibration_fit(pas, x, x, rx_to_world=None, frequency_hz=F)
    with pytest.raises(ConfigError, match="steps"):
        los_calibration_fit(pas, x, y, rx_to_world=None, frequency_hz=F, steps=0)
