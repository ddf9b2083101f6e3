"""rfmitsuba.rf.coarray: the co-array series is the squared Bartlett image, its fit re-renders
an image, and the rank-one inversion recovers known channels up to the twin."""
from __future__ import annotations

import numpy as np
import pytest

from rfmitsuba.core.errors import ConfigError
from rfmitsuba.core.ssim import ssim_images
from rfmitsuba.rf import coarray
from rfmitsuba.rf.array import SPEED_OF_LIGHT
from rfmitsuba.rf.bartlett_ref import bartlett, normalize

F = 920e6
PITCH = 0.5 * SPEED_OF_LIGHT / F


def _channels(seed: int, n: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, 16)) + 1j * rng.normal(size=(n, 16))


def _reals(cl: np.ndarray) -> np.ndarray:
    """complex C_l [25] -> the 49 real coefficients of coarray.basis."""
    out = np.empty(49)
    out[0] = cl[0].real
    out[1::2], out[2::2] = 2 * cl[1:].real, 2 * cl[1:].imag
    return out


def test_lags_are_the_positive_half_of_the_7x7_coarray():
    lg = coarray.lags()
    assert lg.shape == (24, 2)
    full = {tuple(l) for l in lg} | {tuple(-l) for l in lg} | {(0, 0)}
    assert full == {(x, y) for x in range(-3, 4) for y in range(-3, 4)}


def test_series_is_the_squared_bartlett_image_of_the_project_grid():
    h = _channels(0, 3)
    pas = bartlett(h, frequency_hz=F).astype(np.float64)                       # [3, 90, 360], |.| / 16
    B = coarray.basis(coarray.look_directions(elevation_start_deg=1.0), frequency_hz=F, pitch_m=PITCH)
    for k in range(3):
        series = B @ _reals(coarray.channel_lags(h[k])) / 256.0
        np.testing.assert_allclose(series, pas[k].ravel() ** 2, rtol=2e-4, atol=1e-5 * series.max())


def test_coefficients_to_lags_inverts_the_real_layout():
    cl = coarray.channel_lags(_channels(1)[0])
    np.testing.assert_allclose(coarray.coefficients_to_lags(_reals(cl)), cl, atol=1e-12)


@pytest.mark.parametrize("e0", [0.0, 1.0])
def test_fit_rerenders_a_quantised_image_and_finds_its_offset(e0):
    h = _channels(2)[0]
    from rfmitsuba.eval.invert import Geometry, channel_images

    img = channel_images(h[None], Geometry(F, PITCH, e0))[0]
    img8 = np.round(img * 255) / 255
    fit = coarray.CoarrayFit(frequency_hz=F, pitch_m=PITCH, elevation_start_deg=e0).fit(img8)
    assert ssim_images(fit["image"][None], img8[None])[0] > 0.995
    # beta = lo / (hi - lo) of the raw amplitude image
    raw = np.abs(np.exp(-1j * 2 * np.pi * F / SPEED_OF_LIGHT * (coarray.look_directions(elevation_start_deg=e0)
                 @ np.c_[(np.arange(16) % 4 - 1.5) * PITCH, (np.arange(16) // 4 - 1.5) * PITCH, np.zeros(16)].T)) @ h)
    assert fit["beta"] == pytest.approx(raw.min() / (raw.max() - raw.min()), abs=0.02)


def test_fit_on_the_wrong_grid_scores_lower():
    from rfmitsuba.eval.invert import Geometry, channel_images

    img = channel_images(_channels(3), Geometry(F, PITCH, 0.0))[0]
    right = coarray.CoarrayFit(frequency_hz=F, pitch_m=PITCH, elevation_start_deg=0.0).fit(img)["residual"]
    wrong = coarray.CoarrayFit(frequency_hz=F, pitch_m=PITCH, elevation_start_deg=1.0).fit(img)["residual"]
    assert right < 1e-3 < wrong


@pytest.mark.parametrize("seed", [4, 5, 6])
def test_invert_channels_recovers_known_channels_up_to_the_twin(seed):
    h = _channels(seed)[0]
    B = coarray.basis(coarray.look_directions(elevation_start_deg=1.0), frequency_hz=F, pitch_m=PITCH)
    c = _reals(coarray.channel_lags(h))
    est, res = coarray.invert_channels(c, B, starts=6, seed=seed)
    assert res < 1e-4
    assert coarray.channel_error(est, h) < 1e-3


def test_the_twin_draws_the_same_image_and_channel_error_forgives_it():
    h = _channels(7, 2)
    a, b = bartlett(h, frequency_hz=F), bartlett(coarray.twin(h), frequency_hz=F)
    np.testing.assert_allclose(normalize(a), normalize(b), atol=1e-5)
    assert coarray.channel_error(coarray.twin(h[0]) * (2 - 1j), h[0]) < 1e-12
    assert coarray.channel_error(h[1], h[0]) > 0.3


def test_bad_input_is_named():
    with pytest.raises(ConfigError, match="grid"):
        coarray.look_directions(89, 360)
    with pytest.raises(ConfigError, match="positive"):
        coarray.basis(np.zeros((2, 3)), frequency_hz=-1.0, pitch_m=0.16)
    fit = coarray.CoarrayFit(frequency_hz=F, pitch_m=PITCH, height=45, width=180)
    with pytest.raises(ConfigError, match="grid"):
        fit.fit(np.zeros((90, 360)))
    with pytest.raises(ConfigError, match="NaN"):
        fit.fit(np.full((45, 180), np.nan))


def test_phase_only_inversion_fits_phase_only_channels_and_not_free_ones():
    B = coarray.basis(coarray.look_directions(elevation_start_deg=1.0), frequency_hz=F, pitch_m=PITCH)
    rng = np.random.default_rng(8)
    unit = np.exp(1j * rng.uniform(-np.pi, np.pi, 16))
    est, res = coarray.invert_channels(_reals(coarray.channel_lags(unit)), B, starts=32, seed=0, phase_only=True)
    assert res < 1e-4 and coarray.channel_error(est, unit) < 1e-3
    np.testing.assert_allclose(np.abs(est), np.abs(est[0]))
    free = _channels(9)[0]
    _, res_free = coarray.invert_channels(_reals(coarray.channel_lags(free)), B, starts=8, seed=0, phase_only=True)
    assert res_free > 0.05
