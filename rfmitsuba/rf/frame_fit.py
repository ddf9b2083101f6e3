"""Fit the array's frame to the line of sight: a stated gateway orientation checked against the data.

A measured folder states the gateway's orientation (NeRF2's ``gateway_info.yml``), and a stated
frame can be wrong by tens of degrees: a quaternion in another convention, an array mounted
otherwise than written down. A coherent field computes every arrival direction from geometry in
that frame, and its learned pose (:mod:`rfmitsuba.models.coherent_gaussians`) only corrects a few
degrees by gradient descent. This module searches the rotation globally, from the spectra alone.

For each training view the line of sight arrives from ``u = R^T (y - x) / |y - x|`` in the stated
array frame (``R`` = ``rx_to_world``, ``x`` the array centre, ``y`` the transmitter). A candidate
correction ``C`` (a rotation of the array frame) moves it to ``C u``; the single plane wave from
there, read out by the Bartlett beamformer, is the array's beam pattern around ``C u``. The score
of ``C`` is the mean over views of the Pearson correlation between that pattern and the measured
PAS (whole images, so the sidelobes count, not only the peak). The search takes a deterministic
set of candidates within ``max_angle_deg`` of the stated frame, then refines the best few by
Nelder-Mead.

What it can and cannot do (NeRF2-like simulation, 160 training spectra, 4x4 array at 920 MHz):

* with the stated frame right, the best correction is still 6.3 degrees away (the other paths
  pull the apparent line of sight), scoring 0.002 above the stated frame (0.955 against 0.953);
* with the stated frame off by 25 / 45 degrees the stated score drops to 0.932 / 0.290, and the
  search returns the same frame as with a right one (score 0.955), 6.3 degrees from the truth.

So it tells a wrong gateway orientation from a right one reliably, but locates the frame only to
several degrees. :class:`~rfmitsuba.models.coherent_gaussians.CoherentGaussianField` reports it
for measured folders and warns when the stated frame is far off; it does not start from the
fitted frame, which did not raise test SSIM (docs/lab-notes/nerf2like.md, the measured-data
protocols).

Phase-only and amplitude read-outs give the same pattern for one plane wave, so the search
serves both.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import ConfigError
from . import array as antenna
from .bartlett_ref import beamformer


@dataclass(frozen=True)
class FrameFit:
    """Result of :func:`los_frame_fit`.

    rotvec: float64 [3] the correction ``C`` as a rotation vector [rad], in the stated array frame
        (array-frame directions ``u`` become ``C u``).
    score / stated_score: mean correlation of the line-of-sight pattern with the PAS with the
        correction / in the stated frame [1, in -1..1].
    """

    rotvec: np.ndarray
    score: float
    stated_score: float

    @property
    def rotation(self) -> np.ndarray:
        """``C``, float64 [3, 3]."""
        return rotation_matrix(self.rotvec)

    @property
    def angle_deg(self) -> float:
        """Size of the correction [degrees]."""
        return float(np.degrees(np.linalg.norm(self.rotvec)))

    @property
    def gain(self) -> float:
        """``score - stated_score`` [1]."""
        return float(self.score - self.stated_score)

    def rx_to_world(self, stated: np.ndarray) -> np.ndarray:
        """The corrected array frame -> world rotation, float64 [3, 3], from the stated one
        (``R C^T``: world directions map to ``C R^T d`` in the corrected frame)."""
        return np.asarray(stated, np.float64) @ self.rotation.T


def rotation_matrix(rotvec) -> np.ndarray:
    """Rotation matrix float64 [3, 3] of a rotation vector [rad] (Rodrigues)."""
    w = np.asarray(rotvec, np.float64).reshape(3)
    th = float(np.linalg.norm(w))
    if th < 1e-15:
        return np.eye(3)
    k = w / th
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(th) * K + (1.0 - np.cos(th)) * (K @ K)


def _candidates(max_angle: float, count: int, seed: int) -> np.ndarray:
    """Identity plus ``count`` rotation vectors uniform in the ball of radius ``max_angle`` [rad]."""
    rng = np.random.default_rng(seed)
    d = rng.standard_normal((count, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = max_angle * rng.random(count) ** (1.0 / 3.0)
    return np.concatenate([np.zeros((1, 3)), d * r[:, None]])


def line_of_sight_views(pas: np.ndarray, x: np.ndarray, y: np.ndarray, *, rx_to_world: np.ndarray | None,
                        max_views: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    """The views a line-of-sight fit scores, checked: at most ``max_views`` of ``pas`` (float
    [N, H, 4H]), evenly spread, and each one's line-of-sight direction in the array frame.

    Args:
        pas: float [N, H, W] PAS; x, y: float [N, 3] array centres and transmitters [m, world];
        rx_to_world: float [3, 3] array frame -> world, or None (identity); what: the caller's
        name for the errors.
    Returns:
        (float64 [n, H, W] PAS, float64 [n, 3] unit directions from the array to the transmitter).
    Raises:
        ConfigError: shapes that do not match, non-finite values, fewer than 2 views, or a
            transmitter at the array centre.
    """
    pas = np.asarray(pas, np.float64)
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    if pas.ndim != 3 or pas.shape[2] != 4 * pas.shape[1] or x.shape != (len(pas), 3) or y.shape != x.shape:
        raise ConfigError(f"{what}: pas [N, H, 4H] with x, y [N, 3] required, got {pas.shape}, {x.shape}, "
                          f"{y.shape}")
    if len(pas) < 2 or not (np.isfinite(pas).all() and np.isfinite(x).all() and np.isfinite(y).all()):
        raise ConfigError(f"{what}: at least 2 views of finite PAS and positions required")
    los = y - x
    dist = np.linalg.norm(los, axis=1, keepdims=True)
    if (dist < 1e-6).any():
        raise ConfigError(f"{what}: a transmitter sits at the array centre (no line-of-sight direction)")
    if len(pas) > max_views:
        keep = np.unique(np.linspace(0, len(pas) - 1, max_views).round().astype(np.int64))
        pas, los, dist = pas[keep], los[keep], dist[keep]
    R = np.eye(3) if rx_to_world is None else np.asarray(rx_to_world, np.float64).reshape(3, 3)
    return pas, (los / dist) @ R


def los_frame_fit(pas: np.ndarray, x: np.ndarray, y: np.ndarray, *, rx_to_world: np.ndarray | None,
                  frequency_hz: float, max_views: int = 48, max_angle_deg: float = 60.0,
                  candidates: int = 400, refine: int = 4, seed: int = 0) -> FrameFit:
    """Search the rotation of the array frame that best lines the line of sight up with the PAS
    (module docstring).

    Args:
        pas: float [N, H, W] training PAS on the grid of :mod:`rfmitsuba.rf.grid` (any ``90/d x
            360/d``); x, y: float [N, 3] array centres and transmitters [m, world frame].
        rx_to_world: float [3, 3] the stated array frame -> world, or None (identity).
        frequency_hz: carrier [Hz].
        max_views: views scored (evenly spread over the N given).
        max_angle_deg: largest correction searched [degrees].
        candidates: random rotations tried before refining; refine: how many of the best are
            refined (the stated frame always is).
        seed: seeds the candidates.
    Returns:
        :class:`FrameFit`.
    Raises:
        ConfigError: shapes that do not match, non-finite values, fewer than 2 views, or a
            transmitter at the array centre.
    """
    from scipy.optimize import minimize

    pas, u = line_of_sight_views(pas, x, y, rx_to_world=rx_to_world, max_views=max_views, what="los_frame_fit")
    img = pas.reshape(len(pas), -1)
    img = img - img.mean(1, keepdims=True)
    img /= np.maximum(np.linalg.norm(img, axis=1, keepdims=True), 1e-12)
    pos = antenna.element_positions(frequency_hz)
    kw = 2.0 * np.pi / antenna.wavelength(frequency_hz)
    weights = beamformer(frequency_hz=frequency_hz, resolution_deg=90.0 / pas.shape[1]).astype(np.complex128)

    def score(rv: np.ndarray) -> float:
        h = np.exp(1j * kw * ((u @ rotation_matrix(rv).T) @ pos.T))      # [N, 16] one plane wave each
        pat = np.abs(h @ weights.T)                                      # [N, pixels]
        pat -= pat.mean(1, keepdims=True)
        pat /= np.maximum(np.linalg.norm(pat, axis=1, keepdims=True), 1e-12)
        return float((pat * img).sum(1).mean())

    cand = _candidates(np.radians(max_angle_deg), candidates, seed)
    sc = np.array([score(c) for c in cand])
    starts = [cand[0]] + [cand[i] for i in np.argsort(-sc)[:refine] if i != 0]
    best_v, best_s = cand[0], sc[0]
    for s0 in starts:
        r = minimize(lambda v: -score(v), s0, method="Nelder-Mead",
                     options={"xatol": 1e-3, "fatol": 1e-6, "maxfev": 300})
        if -r.fun > best_s and np.linalg.norm(r.x) <= np.radians(max_angle_deg) * 1.25:
            best_v, best_s = np.asarray(r.x, np.float64), float(-r.fun)
    return FrameFit(rotvec=best_v, score=best_s, stated_score=float(sc[0]))
