"""Power Angular Spectrum (docs/conventions.md): Bartlett beamformer of the 4x4 horizontal array.

Layout: image [90, 360] at 1 degree, row ``i`` = elevation ``(i + 1) * res``
degrees above the array plane, column ``j`` = azimuth ``j * res`` degrees from
+x towards +y (array frame).

Value: ``P(el, az) = | sum_m conj(v_m(el, az)) h_m | / M`` with the element's
plane-wave response ``v_m = exp(+j 2 pi / lambda * r_m . d(el, az))`` and
``d = (cos el cos az, cos el sin az, sin el)``. The sign of the exponent is
the one that makes the peak point at the source for Sionna RT's channels
(``a exp(-j 2 pi f tau)``, see :mod:`rfmitsuba.rf.array`); an older specification's written
``a_m = exp(-j ...)`` is the complex conjugate convention and would put every
peak 180 degrees away in azimuth.

All K images come from one complex matrix product ``[pixels, 16] x [16, K]``.

Phase-only read-out (``bartlett(..., phase_only=True)``): NeRF2's RFID spectra use each
element's measured phase with unit magnitude, ``h_m / |h_m|`` (:func:`unit_modulus`), so the
per-element amplitudes do not matter. NeRF2 writes its steering vector as ``exp(-j ...)``
because its measured phases have the opposite sign to Sionna's channel; applied to
``conj(h)`` that is the same image as the ``+j`` convention here applied to ``h``.
"""
from __future__ import annotations

import functools
import threading

import numpy as np
from threadpoolctl import threadpool_limits

from ..core.errors import ConfigError
from . import array as antenna
from .grid import angle_grid, directions


def beamformer(*, frequency_hz: float, positions: np.ndarray | None = None,
               resolution_deg: float = 1.0) -> np.ndarray:
    """Bartlett weights conj(v_m(pixel)) / M: complex64 [H*W, M]."""
    pos = antenna.element_positions(frequency_hz) if positions is None else np.asarray(positions, np.float64)
    k = 2.0 * np.pi / antenna.wavelength(frequency_hz)
    d = directions(resolution_deg=resolution_deg).reshape(-1, 3)
    return (np.exp(-1j * k * (d @ pos.T)) / pos.shape[0]).astype(np.complex64)


@functools.lru_cache(maxsize=8)
def _default_weights(frequency_hz: float, resolution_deg: float) -> np.ndarray:
    """:func:`beamformer` of the default array, kept read-only between calls of :func:`bartlett`
    (a dataset calls it once per state; the weights took 77 ms of a 900-channel state's 0.35 s)."""
    w = beamformer(frequency_hz=frequency_hz, resolution_deg=resolution_deg)
    w.flags.writeable = False
    return w


def unit_modulus(channels: np.ndarray) -> np.ndarray:
    """Each element's phase with unit magnitude, ``h / |h|``: complex128 of the same shape
    (elements with ``h = 0`` have no phase and stay 0)."""
    h = np.asarray(channels, np.complex128)
    mag = np.abs(h)
    return np.where(mag > 0, h / np.where(mag > 0, mag, 1.0), 0)


#: per thread: the complex scratch of :func:`bartlett`'s matrix products, kept between calls
_SCRATCH = threading.local()


def _scratch(pixels: int, columns: int) -> np.ndarray:
    """A C-contiguous complex64 [pixels, columns] work array of this thread, on memory reused
    between calls (grown when a call needs more): fresh pages for every product cost more than
    the product (:func:`bartlett`)."""
    buf = getattr(_SCRATCH, "buf", None)
    if buf is None or buf.size < pixels * columns:
        buf = _SCRATCH.buf = np.empty(pixels * columns, np.complex64)
    return buf[:pixels * columns].reshape(pixels, columns)


def bartlett(channels: np.ndarray, *, frequency_hz: float, positions: np.ndarray | None = None,
             resolution_deg: float = 1.0, batch: int = 64, phase_only: bool = False,
             out: np.ndarray | None = None) -> np.ndarray:
    """Bartlett PAS of K channels.

    Args:
        channels: complex [K, M] narrowband channel per element (M = 16).
        frequency_hz: carrier, Hz.
        positions: element offsets float [M, 3], metres (default: the 4x4 URA).
        resolution_deg: angular step (1 -> [90, 360] images).
        batch: images per matrix product (bounds memory: a complex64 [H*W, batch] work array per
            thread, 16.6 MB at 1 degree and 64, kept between calls); each product is padded with
            zeros to a multiple of 8 images, so every image has the same bits however many
            channels come in one call, from which offset, and whatever ``batch`` (a multiple of 8).
        phase_only: use ``h_m / |h_m|`` (:func:`unit_modulus`) instead of ``h_m``, as NeRF2's
            RFID spectra do; the image is then independent of the per-element amplitudes.
        out: float32 C-contiguous [K, H, W] to write the images into (a caller making many
            states reuses one), or None for a new array.
    Returns:
        float32 [K, H, W] (``out`` when given), raw linear amplitude (at most 1 with ``phase_only``).

    Memory is reused, not allocated per call: the products go through one work array per thread
    and a caller may pass ``out``. Fresh pages for every state cost more than the arithmetic: in a
    dataset worker beside another (900 channels per state, 2 cores), a state's images took
    0.36-0.99 s with 0.18-0.69 s of it in the kernel (page faults), against 0.16-0.18 s with the
    memory reused. Padding to multiples of 8 changed the last bits of the images in the last
    ``K mod 8`` places of a call (BLAS computes the columns past the last multiple of 8 with
    another kernel): 4 of a 900-channel state's images differ from those of datasets made before
    2026-11-28.
    Calls from several threads at once each use their own work
    array; their images may differ from a lone call's in the last float bit (BLAS's thread limit
    is process-wide).
    """
    h = np.asarray(channels)
    if h.ndim != 2:
        raise ConfigError(f"channels must be [K, M], got shape {h.shape}")
    if not np.isfinite(h).all():
        raise ConfigError("channels contain NaN or inf")
    if int(batch) < 1:
        raise ConfigError(f"batch must be >= 1, got {batch}")
    if phase_only:
        h = unit_modulus(h)
    B = (_default_weights(float(frequency_hz), float(resolution_deg)) if positions is None else
         beamformer(frequency_hz=frequency_hz, positions=positions, resolution_deg=resolution_deg))
    if h.shape[1] != B.shape[1]:
        raise ConfigError(f"channels have {h.shape[1]} elements, the array has {B.shape[1]}")
    el, _ = angle_grid(resolution_deg=resolution_deg)
    shape = (h.shape[0], *el.shape)
    if out is None:
        out = np.empty(shape, np.float32)
    elif not (isinstance(out, np.ndarray) and out.shape == shape and out.dtype == np.float32
              and out.flags.c_contiguous and out.flags.writeable):
        raise ConfigError(f"out must be a writeable C-contiguous float32 array of shape {shape}, got "
                          f"{getattr(out, 'dtype', type(out).__name__)} {getattr(out, 'shape', '')}")
    hc = h.astype(np.complex64)
    batch = int(batch)
    # every product's width is a multiple of 8 columns, a short one padded with zeros: BLAS
    # computes the columns past the last multiple of 8 with another kernel, whose last bits
    # differ, so an image's bits would depend on how many channels were beamformed with it (the
    # noisy samples of one state come in sets of any size)
    pad = np.zeros((batch + 7, hc.shape[1]), np.complex64)
    # one BLAS thread: OpenBLAS may take another kernel path with another thread count, which
    # changes the last float bit; Dask workers run with one, so a dataset state is bit-identical
    # whichever process made it (tests/core/test_cluster.py)
    with threadpool_limits(limits=1, user_api="blas"):
        for s in range(0, h.shape[0], batch):
            k = min(batch, h.shape[0] - s)
            width = -(-k // 8) * 8
            rows = hc[s:s + k]
            if width > k:
                pad[:k] = rows
                pad[k:width] = 0
                rows = pad[:width]
            work = _scratch(B.shape[0], width)
            np.matmul(B, rows.T, out=work)  # [pixels, 16] x [16, width]
            # the magnitudes go straight into the images through a transposed view: no
            # [pixels, k] temporary and no strided copy (the copy was 3x the product's time)
            np.abs(work[:, :k], out=out[s:s + k].reshape(k, -1).T)
    return out


def normalize(pas: np.ndarray) -> np.ndarray:
    """Per-image min-max to [0, 1]: float32 of the same shape [..., H, W]; constant images give 0."""
    p = np.asarray(pas, np.float32)
    lo = p.min(axis=(-2, -1), keepdims=True)
    span = p.max(axis=(-2, -1), keepdims=True) - lo
    out = np.subtract(p, lo)   # (p - lo) / span in float32, written into one new array
    np.divide(out, np.where(span > 0, span, np.float32(1)), out=out)
    out[np.broadcast_to(~(span > 0), out.shape)] = 0   # constant (or NaN) images: 0
    return out


def peak_direction(pas: np.ndarray, *, resolution_deg: float = 1.0) -> tuple[float, float]:
    """(elevation, azimuth) in radians of the brightest pixel of one image [H, W]."""
    i, j = np.unravel_index(int(np.argmax(pas)), np.shape(pas))
    el, az = angle_grid(resolution_deg=resolution_deg)
    return float(el[i, j]), float(az[i, j])
