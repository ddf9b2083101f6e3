"""Tests of rfmitsuba.rf.array: URA geometry and the plane-wave array response."""
import numpy as np
import pytest

from rfmitsuba.core.errors import ConfigError
from rfmitsuba.rf import array as antenna


def test_wavelength_2_4ghz():
    assert antenna.wavelength(2.4e9) == pytest.approx(0.12491352, rel=1e-6)


@pytest.mark.parametrize("f", [0.0, -1.0, float("nan"), float("inf")])
def test_wavelength_rejects_bad_frequency(f):
    with pytest.raises(ConfigError, match="frequency_hz"):
        antenna.wavelength(f)


def test_element_positions_half_wavelength_x_fastest():
    lam = antenna.wavelength(2.4e9)
    p = antenna.element_positions(2.4e9)
    assert p.shape == (16, 3)
    assert np.allclose(p[:, 2], 0)  # horizontal array
    assert np.allclose(p.mean(axis=0), 0)  # centred
    assert np.isclose(p[1, 0] - p[0, 0], lam / 2) and np.isclose(p[1, 1], p[0, 1])  # x fastest
    assert np.isclose(p[4, 1] - p[0, 1], lam / 2) and np.isclose(p[4, 0], p[0, 0])
    assert np.isclose(p[:, 0].max() - p[:, 0].min(), 1.5 * lam)


def test_array_response_matches_explicit_sum():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(3, 5)) + 1j * rng.normal(size=(3, 5))
    u = rng.normal(size=(3, 5, 3))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    pos = antenna.element_positions(2.4e9)
    k = 2 * np.pi / antenna.wavelength(2.4e9)
    ref = np.array([[sum(a[n, p] * np.exp(1j * k * pos[m] @ u[n, p]) for p in range(5)) for m in range(16)]
                    for n in range(3)])
    assert np.allclose(antenna.array_response(a, u, frequency_hz=2.4e9), ref, rtol=1e-5, atol=1e-6)


def test_array_response_has_the_same_bits_in_blocks(monkeypatch):
    """Positions in blocks of ``RESPONSE_ROWS`` (here 4 of 10, the last block short) give the
    bits of one block holding them all: datasets do not change with the block size."""
    rng = np.random.default_rng(2)
    a = (rng.normal(size=(10, 7)) + 1j * rng.normal(size=(10, 7))) * (rng.random((10, 7)) < 0.7)
    u = rng.normal(size=(10, 7, 3))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    whole = antenna.array_response(a, u, frequency_hz=2.4e9)
    monkeypatch.setattr(antenna, "RESPONSE_ROWS", 4)
    assert np.array_equal(antenna.array_response(a, u, frequency_hz=2.4e9), whole)
    assert whole.dtype == np.complex64 and whole.shape == (10, 16)


def test_array_response_shape_mismatch():
    with pytest.raises(ConfigError, match="directions"):
        antenna.array_response(np.ones((2, 3)), np.ones((2, 4, 3)), frequency_hz=2.4e9)


def test_describe_records_geometry():
    d = antenna.describe(2.4e9)
    assert d["rows"] == 4 and d["cols"] == 4 and len(d["element_positions_m"]) == 16


def test_half_power_beamwidth_is_where_the_array_response_falls_3_db():
    from rfmitsuba.rf.array import array_response, half_power_beamwidth_deg, unit_vectors

    bw = half_power_beamwidth_deg()
    assert abs(bw - np.degrees(0.886 / 2)) < 1.5                  # the long-row rule, 25.4 degrees
    # the 4x4 array's Bartlett power towards broadside, for a plane wave tilted by bw / 2 in x-z
    f = 2.4e9
    half = np.radians(bw / 2)
    def h(theta):
        return array_response(np.ones((1, 1)), unit_vectors(np.array([theta]), np.array([0.0]))[None], frequency_hz=f)

    a, b = h(half).ravel().astype(np.complex128), h(0.0).ravel().astype(np.complex128)
    gain = abs(np.vdot(b, a)) / abs(np.vdot(b, b))
    assert abs(gain - 2 ** -0.5) < 1e-5
