"""Fit the array's per-element phase calibration to the line of sight, from the spectra alone.

A real array's elements carry phase offsets (cables, phase centres, the reader's ports) of any
size: NeRF2's RFID gateway publishes its spectra with them in. The coherent Gaussian field
learns a complex calibration per element (``cal`` of
:class:`~rfmitsuba.models.coherent_gaussians.CoherentGaussianField`), but by gradient descent
from no offset: offsets of tens of degrees are found, offsets anywhere in +-180 degrees leave it
in a local minimum (NeRF2-like tags, +-180 degrees: 0.903 test SSIM against IDW-3's 0.961).

This module searches the offsets globally, as :mod:`rfmitsuba.rf.frame_fit` searches the frame.
For each training view the line of sight arrives from ``u`` (array frame); with offsets ``c_m``
the element channels are ``exp(j (k u . r_m + c_m))`` and the Bartlett read-out of that one
wave is the array's pattern, distorted by the offsets. The score of ``c`` is the mean over
views of the Pearson correlation between that pattern and the measured PAS (whole images).
Coordinate search: each element's offset in turn takes the best of ``steps`` values in [0, 2 pi)
with the others held, a few sweeps, from no offset and from seeded random starts, then basin
hopping (a few elements of the best offsets drawn anew, searched again, kept where better);
the best is refined on a grid twice as fine. Element 0 is the reference (its offset stays 0: a common
phase changes no spectrum).

Line-of-sight spectra cannot tell offsets ``g_m`` from their twin, ``conj(g)`` with the element
order reversed along both axes (up to a common phase, the same spectra at every view: the
phase-retrieval twin), nor a linear ramp across the elements from a beam tilt of a degree or
two (tags in a small patch barely tell it from the frame; the field's learned pose absorbs
it). Of the two twins the fit returns the one nearer no offset (larger ``|sum_m g_m|``): with
no ramp added that is the true one where offsets are tens of degrees, but a ramp can hide it,
and for offsets anywhere in +-180 degrees either is as likely. The twin is returned too
(:attr:`CalibrationFit.twin_phase_rad`). For tags in a patch far from the gateway the field
trains as well from either (NeRF2-like tags, +-180 degrees, seed 0: test SSIM 0.964 and 0.966),
and each stays on its own twin, so the field starts from the nearer one.

A pattern of one plane wave is the same for the amplitude and the phase-only read-out (unit
channels), so the search serves both.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import ConfigError
from . import array as antenna
from .bartlett_ref import beamformer
from .frame_fit import line_of_sight_views


@dataclass(frozen=True)
class CalibrationFit:
    """Result of :func:`los_calibration_fit`.

    phase_rad: float64 [M] per-element phase offsets [rad], element 0 = 0: the channel the field
        computes is multiplied by ``exp(j phase_rad)`` (:attr:`cal`).
    score / stated_score: mean correlation of the line-of-sight pattern with the PAS with the
        offsets / with none [1, in -1..1].
    twin_phase_rad: float64 [M] the offsets' twin (``conj`` with the element order reversed on
        both axes, element 0 = 0) [rad]: the same line-of-sight spectra, so equally likely where
        only the line of sight is scored (module docstring); ``twin_score`` its score [1].
    """

    phase_rad: np.ndarray
    score: float
    stated_score: float
    twin_phase_rad: np.ndarray
    twin_score: float

    @property
    def cal(self) -> np.ndarray:
        """The per-element calibration ``exp(j phase_rad)``: complex128 [M]."""
        return np.exp(1j * self.phase_rad)

    @property
    def twin_cal(self) -> np.ndarray:
        """The twin's calibration ``exp(j twin_phase_rad)``: complex128 [M]."""
        return np.exp(1j * self.twin_phase_rad)

    @property
    def gain(self) -> float:
        """``score - stated_score`` [1]."""
        return float(self.score - self.stated_score)


def _unit_rows(a: np.ndarray) -> np.ndarray:
    """Rows (last axis) centred and scaled to unit norm."""
    a = a - a.mean(-1, keepdims=True)
    return a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-12)


def los_calibration_fit(pas: np.ndarray, x: np.ndarray, y: np.ndarray, *, rx_to_world: np.ndarray | None,
                        frequency_hz: float, max_views: int = 12, pixel_stride: int = 4, steps: int = 36,
                        sweeps: int = 3, restarts: int = 8, hops: int = 48, hop_elements: int = 4,
                        seed: int = 0) -> CalibrationFit:
    """Search the per-element phase offsets that best draw the line of sight in the PAS (module
    docstring).

    Args:
        pas: float [N, H, W] training PAS on the grid of :mod:`rfmitsuba.rf.grid` (any ``90/d x
            360/d``); x, y: float [N, 3] array centres and transmitters [m, world frame].
        rx_to_world: float [3, 3] the array frame -> world, or None (identity).
        frequency_hz: carrier [Hz].
        max_views: views scored (evenly spread over the N given).
        pixel_stride: every ``pixel_stride``-th row and column of the PAS is scored.
        steps: offsets tried per element and sweep (the refinement tries twice as many).
        sweeps: passes over the elements per start.
        restarts: random starts besides no offset.
        hops: basin-hopping rounds after the starts: ``hop_elements`` elements of the best
            offsets so far are drawn anew and the search runs again; the better result is kept.
            With 4 restarts and 24 hops the search missed the best offsets on 1 seed of 10 on
            a NeRF2-like folder with +-180 degree offsets (correlation 0.787 against 0.869; the
            same at 10 dB: 0.716 against 0.787), and training from there reached 0.863 against
            0.964-0.967 (IDW-3 0.961); with 8 and 48 on none of 10, in about 7 s on 2 cores.
        seed: seeds the random starts.
    Returns:
        :class:`CalibrationFit`.
    Raises:
        ConfigError: shapes that do not match, non-finite values, fewer than 2 views, a
            transmitter at the array centre, ``steps``, ``sweeps``, ``pixel_stride`` or
            ``hop_elements`` < 1, or ``restarts`` or ``hops`` < 0.
    """
    if min(steps, sweeps, pixel_stride, hop_elements) < 1 or min(restarts, hops) < 0:
        raise ConfigError(f"los_calibration_fit: steps, sweeps, pixel_stride, hop_elements >= 1 and restarts, hops "
                          f">= 0 required, got {steps}, {sweeps}, {pixel_stride}, {hop_elements}, {restarts}, {hops}")
    pas, u = line_of_sight_views(pas, x, y, rx_to_world=rx_to_world, max_views=max_views, what="los_calibration_fit")
    n, h, w = pas.shape
    rows, cols = np.arange(0, h, pixel_stride), np.arange(0, w, pixel_stride)
    pix = (rows[:, None] * w + cols[None, :]).ravel()
    img = _unit_rows(pas.reshape(n, -1)[:, pix])                        # [N, P]
    pos = antenna.element_positions(frequency_hz)
    k = 2.0 * np.pi / antenna.wavelength(frequency_hz)
    weights = beamformer(frequency_hz=frequency_hz, resolution_deg=90.0 / h).astype(np.complex128)[pix]  # [P, M]
    # one term per view, element and pixel: weight times the element's line-of-sight phase
    terms = np.exp(1j * k * (u @ pos.T))[:, :, None] * weights.T[None]  # [N, M, P]
    m_count = terms.shape[1]

    def score_of(sums: np.ndarray) -> np.ndarray:
        """Mean correlation over views of |sums| ([..., N, P]) with the PAS: [...]."""
        return (_unit_rows(np.abs(sums)) * img).sum(-1).mean(-1)

    def score_at(c: np.ndarray) -> float:
        """The score of offsets ``c`` (float [M] rad)."""
        return float(score_of(np.einsum("nmp,m->np", terms, np.exp(1j * c))))

    def search(c: np.ndarray, grid: np.ndarray, passes: int) -> tuple[np.ndarray, float]:
        c = c.copy()
        rot = np.exp(1j * grid)[:, None, None]
        total = np.einsum("nmp,m->np", terms, np.exp(1j * c))
        for _ in range(passes):
            for m in range(1, m_count):
                rest = total - terms[:, m] * np.exp(1j * c[m])
                s = score_of(rest[None] + terms[None, :, m] * rot)            # [G]
                c[m] = grid[int(np.argmax(s))]
                total = rest + terms[:, m] * np.exp(1j * c[m])
        return c, float(score_of(total))

    none = np.zeros(m_count)
    stated = score_at(none)
    rng = np.random.default_rng(seed)
    grid = 2.0 * np.pi * np.arange(steps) / steps
    starts = [none] + [np.concatenate([[0.0], rng.uniform(0, 2 * np.pi, m_count - 1)]) for _ in range(restarts)]
    best_c, best_s = none, stated
    for c0 in starts:
        c, s = search(c0, grid, sweeps)
        if s > best_s:
            best_c, best_s = c, s
    for _ in range(hops):                  # basin hopping: a few elements of the best start anew
        c0 = best_c.copy()
        pick = rng.choice(np.arange(1, m_count), size=min(hop_elements, m_count - 1), replace=False)
        c0[pick] = rng.uniform(0, 2 * np.pi, len(pick))
        c, s = search(c0, grid, sweeps)
        if s > best_s:
            best_c, best_s = c, s
    fine = 2.0 * np.pi * np.arange(2 * steps) / (2 * steps)
    c, s = search(best_c, fine, 2)
    if s > best_s:
        best_c, best_s = c, s
    # the twin: conj(g) with both axes reversed draws the same line-of-sight spectra (a linear
    # phase stays linear under it); of the two, keep the one nearer no offset (|sum_m g_m|)
    twin = _twin(best_c)
    t_score = score_at(twin)
    if t_score >= best_s - 1e-3 and abs(np.exp(1j * twin).sum()) > abs(np.exp(1j * best_c).sum()):
        best_c, best_s, twin, t_score = twin, t_score, best_c, best_s
    return CalibrationFit(phase_rad=_wrap(best_c), score=best_s, stated_score=stated, twin_phase_rad=_wrap(twin),
                          twin_score=t_score)


def _twin(c: np.ndarray) -> np.ndarray:
    """The twin of offsets ``c`` (float [M] rad, elements in the array's row-major order): ``-c``
    with the element order reversed on both axes (a point reflection of the array), re-referenced
    to element 0."""
    t = -np.asarray(c, np.float64)[::-1]
    return t - t[0]


def _wrap(c: np.ndarray) -> np.ndarray:
    """Phases [rad] wrapped into (-pi, pi]."""
    return np.angle(np.exp(1j * np.asarray(c, np.float64)))
