"""The 4x4 horizontal uniform rectangular array (docs/conventions.md, "Antennas") and its plane-wave response.

Element ``m = row * cols + col`` (x fastest) sits at
``x = (col - (cols-1)/2) * d``, ``y = (row - (rows-1)/2) * d``, ``z = 0`` in the
array frame, ``d`` = half a wavelength; the array frame's axes are the world
axes (array horizontal, normal +z).

Phase convention (measured with Sionna RT 2.2, see tests/test_antenna.py): the
baseband channel is ``a * exp(-j 2 pi f tau)``, so an element displaced by
``r`` towards a source in unit direction ``u`` receives
``exp(+j 2 pi / lambda * r . u)`` times the centre's channel.
"""
from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError

#: Speed of light in vacuum, m/s (same constant as Sionna RT).
SPEED_OF_LIGHT = 299_792_458.0
ROWS = 4
COLS = 4
#: number of array elements (ROWS x COLS)
NUM_ELEMENTS = ROWS * COLS
SPACING_WAVELENGTHS = 0.5


def wavelength(frequency_hz: float) -> float:
    """Wavelength in metres of a carrier ``frequency_hz`` (Hz, > 0)."""
    f = float(frequency_hz)
    if not np.isfinite(f) or f <= 0:
        raise ConfigError(f"frequency_hz must be a positive finite number, got {frequency_hz!r}")
    return SPEED_OF_LIGHT / f


def element_positions(frequency_hz: float, *, rows: int = ROWS, cols: int = COLS,
                      spacing_wavelengths: float = SPACING_WAVELENGTHS) -> np.ndarray:
    """Element offsets from the array centre: float64 [rows*cols, 3], metres, array frame, x fastest."""
    if rows < 1 or cols < 1:
        raise ConfigError(f"array needs rows, cols >= 1, got {rows}x{cols}")
    d = spacing_wavelengths * wavelength(frequency_hz)
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    x = (c.ravel() - (cols - 1) / 2.0) * d
    y = (r.ravel() - (rows - 1) / 2.0) * d
    return np.stack([x, y, np.zeros_like(x)], axis=1)


def half_power_beamwidth_deg(*, cols: int = COLS, spacing_wavelengths: float = SPACING_WAVELENGTHS) -> float:
    """Half-power (-3 dB) beamwidth [degrees] of the array's main beam at broadside, along one
    row of ``cols`` elements ``spacing_wavelengths`` apart: twice the angle where the row's
    array factor ``|sum_n exp(j 2 pi s n sin(theta))| / cols`` falls to ``1 / sqrt(2)``
    (26.3 degrees for the 4x4 array at half a wavelength; ``0.886 / (cols s)`` rad for long rows)."""
    if cols < 2 or not spacing_wavelengths > 0:
        raise ConfigError(f"a beamwidth needs cols >= 2 and spacing > 0, got {cols}, {spacing_wavelengths!r}")
    lo, hi = 0.0, min(1.0, 1.0 / (cols * spacing_wavelengths))     # the first null, or endfire
    n = np.arange(cols)
    for _ in range(60):                                              # bisection on u = sin(theta)
        u = (lo + hi) / 2
        af = abs(np.exp(2j * np.pi * spacing_wavelengths * n * u).sum()) / cols
        lo, hi = (u, hi) if af > 2 ** -0.5 else (lo, u)
    return float(np.degrees(2 * np.arcsin((lo + hi) / 2)))


def describe(frequency_hz: float) -> dict:
    """The array geometry as recorded in a dataset's meta.json."""
    return {
        "type": "URA", "rows": ROWS, "cols": COLS, "spacing_wavelengths": SPACING_WAVELENGTHS,
        "element_order": "x fastest: m = row * cols + col",
        "orientation": "horizontal: elements in the world x-y plane, normal +z",
        "element_pattern": "iso", "polarization": "V",
        "element_positions_m": element_positions(frequency_hz).tolist(),
    }


def unit_vectors(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Unit vectors of zenith ``theta`` and azimuth ``phi`` (radians, Sionna convention): [..., 3]."""
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)


#: positions per block of :func:`array_response`
RESPONSE_ROWS = 256


def array_response(a: np.ndarray, directions: np.ndarray, *, frequency_hz: float,
                   positions: np.ndarray | None = None) -> np.ndarray:
    """Narrowband channel at each element from per-path coefficients (plane-wave, synthetic array).

    ``h[n, m] = sum_p a[n, p] * exp(+j 2 pi / lambda * r_m . u[n, p])``

    Args:
        a: complex [N, P] baseband path coefficients (zero for padded paths).
        directions: float [N, P, 3] unit vectors from the array towards each path's
            first hop (arrival direction at a receiving array, departure at a transmitting one).
        frequency_hz: carrier, Hz.
        positions: element offsets float [M, 3], metres (default :func:`element_positions`).
    Returns:
        complex64 [N, M].
    """
    pos = element_positions(frequency_hz) if positions is None else np.asarray(positions, np.float64)
    k = 2.0 * np.pi / wavelength(frequency_hz)
    a = np.asarray(a, np.complex128)
    u = np.asarray(directions, np.float64)
    if u.shape != (*a.shape, 3):
        raise ConfigError(f"directions must be {(*a.shape, 3)}, got {u.shape}")
    h = np.empty((a.shape[0], pos.shape[0]), np.complex64)
    # RESPONSE_ROWS positions at a time: the [rows, P, M] phases stay small and their memory is
    # reused (7500 positions at once: 0.66 s, most of it in fresh pages); the same bits either way
    for lo in range(0, a.shape[0], RESPONSE_ROWS):
        hi = lo + RESPONSE_ROWS
        phase = np.einsum("npc,mc->npm", u[lo:hi], pos) * k  # [rows, P, M]
        h[lo:hi] = np.einsum("np,npm->nm", a[lo:hi], np.exp(1j * phase))
    return h
