"""Measurement inversion: the co-array coefficients and rank-one channels of every spectrum of
a dataset, and the carrier, pitch and grid the spectra imply (:mod:`rfmitsuba.rf.coarray`).

A diagnostic, not a model: it says what a spectrum can hold (49 numbers; 31 where it is the
Bartlett image of one set of channels) and whether the stated carrier, pitch and image grid
are the ones that drew it.

- **Co-array fit**: every image's 49 coefficients; its re-render SSIM says how well a Bartlett
  spectrum on the assumed grid explains the image at all.
- **Channels**: where the image is rank one, the 16 complex element channels (up to a common
  complex factor and the twin, :func:`rfmitsuba.rf.coarray.twin`), and their re-render SSIM.
  A phase-only read-out (unit-modulus channels) is a special case; the ratio of the smallest to
  the largest element magnitude says how far the recovered channels are from it.
- **Implied geometry**: the co-array fit's mean SSIM on a subset of images over a scan of the
  electrical pitch ``d / lambda`` and of the elevation of row 0 (0 or 1 degree); the best gives
  the implied carrier at the stated pitch and the implied pitch at the stated carrier.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.errors import ConfigError
from ..core.ssim import ssim_images
from ..rf import coarray
from ..rf.array import SPEED_OF_LIGHT, element_positions

#: elevations [degrees] of row 0 that the geometry scan tries: NeRF2's published images, the project's grid
ELEVATION_STARTS_DEG = (0.0, 1.0)


@dataclass(frozen=True)
class Geometry:
    """The grid and array an inversion assumes.

    frequency_hz: carrier [Hz]; pitch_m: element pitch [m]; elevation_start_deg: elevation of
    row 0 [degrees].
    """

    frequency_hz: float
    pitch_m: float
    elevation_start_deg: float

    @property
    def pitch_wavelengths(self) -> float:
        """Electrical pitch ``d / lambda`` (what the images can tell)."""
        return self.pitch_m * self.frequency_hz / SPEED_OF_LIGHT


@dataclass
class Inversion:
    """Per-image results of :func:`invert_images` (N images).

    coarray_ssim: float64 [N] re-render SSIM of the co-array fit; channel_ssim: float64 [N]
    re-render SSIM of the rank-one channels; coefficients: float64 [N, 49]; beta: float64 [N]
    offsets of the normalisation; channels: complex128 [N, 16] (``h_0`` real, unit norm);
    magnitude_ratio: float64 [N] smallest over largest element magnitude (1 for a phase-only
    read-out); geometry: the grid and array used; scan: rows of the geometry scan.
    """

    coarray_ssim: np.ndarray
    channel_ssim: np.ndarray
    coefficients: np.ndarray
    beta: np.ndarray
    channels: np.ndarray
    magnitude_ratio: np.ndarray
    geometry: Geometry
    scan: list = field(default_factory=list)
    coarray_images: np.ndarray | None = None
    channel_images: np.ndarray | None = None


def channel_images(h: np.ndarray, geometry: Geometry, *, height: int = 90, width: int = 360) -> np.ndarray:
    """Normalised amplitude Bartlett images of channels complex [N, 16] on ``geometry``'s grid:
    float64 [N, height, width]."""
    d = coarray.look_directions(height, width, elevation_start_deg=geometry.elevation_start_deg)
    pos = element_positions(geometry.frequency_hz,
                            spacing_wavelengths=geometry.pitch_wavelengths)
    k = 2 * np.pi * geometry.frequency_hz / SPEED_OF_LIGHT
    w = np.exp(-1j * k * (d @ pos.T))
    p = np.abs(np.asarray(h, np.complex128) @ w.T).reshape(-1, height, width)
    lo, hi = p.min((1, 2), keepdims=True), p.max((1, 2), keepdims=True)
    return (p - lo) / np.maximum(hi - lo, 1e-300)


def scan_geometry(images: np.ndarray, *, frequency_hz: float, pitch_m: float,
                  pitch_wavelengths: np.ndarray | None = None,
                  elevation_starts_deg=ELEVATION_STARTS_DEG) -> tuple[Geometry, list[dict]]:
    """The grid and electrical pitch under which the co-array fit of ``images`` (float [N, 90,
    360], normalised) scores best: (the best :class:`Geometry` at the stated ``pitch_m``, the scan's
    rows ``{"elevation_start_deg", "pitch_wavelengths", "ssim_mean"}``)."""
    imgs = np.asarray(images, np.float64)
    stated = pitch_m * frequency_hz / SPEED_OF_LIGHT
    grid = (np.round(np.arange(0.40, 0.6001, 0.01), 4) if pitch_wavelengths is None
            else np.asarray(pitch_wavelengths, np.float64))
    grid = np.unique(np.r_[grid, stated])
    rows = []
    for e0 in elevation_starts_deg:
        for pw in grid:
            fit = coarray.CoarrayFit(frequency_hz=frequency_hz, pitch_m=pw * SPEED_OF_LIGHT / frequency_hz,
                                     height=imgs.shape[1], width=imgs.shape[2], elevation_start_deg=e0)
            rec = np.stack([fit.fit(im)["image"] for im in imgs])
            rows.append({"elevation_start_deg": float(e0), "pitch_wavelengths": float(pw),
                         "ssim_mean": float(ssim_images(rec, imgs).mean())})
    best = max(rows, key=lambda r: r["ssim_mean"])
    pw = best["pitch_wavelengths"]
    return Geometry(frequency_hz=pw * SPEED_OF_LIGHT / pitch_m, pitch_m=pitch_m,
                    elevation_start_deg=best["elevation_start_deg"]), rows


def invert_images(images: np.ndarray, geometry: Geometry, *, starts: int = 16, seed: int = 0,
                  keep_images: bool = False, quiet: bool = True) -> Inversion:
    """Co-array coefficients and rank-one channels of every image.

    Args:
        images: float [N, H, W] min-max normalised spectra on ``geometry``'s grid.
        geometry: carrier [Hz], pitch [m] and elevation of row 0 [degrees].
        starts: seeded starts of each channel fit (:func:`rfmitsuba.rf.coarray.invert_channels`).
        seed: their seed; keep_images: keep both re-renders [N, H, W]; quiet: no progress bar.
    """
    from ..core import progress

    imgs = np.asarray(images, np.float64)
    if imgs.ndim != 3 or len(imgs) == 0:
        raise ConfigError(f"invert_images needs images [N, H, W] with N >= 1, got shape {imgs.shape}")
    fit = coarray.CoarrayFit(frequency_hz=geometry.frequency_hz, pitch_m=geometry.pitch_m,
                             height=imgs.shape[1], width=imgs.shape[2],
                             elevation_start_deg=geometry.elevation_start_deg)
    n = len(imgs)
    coef, beta = np.empty((n, 49)), np.empty(n)
    chans = np.empty((n, 16), np.complex128)
    rec = np.empty_like(imgs)
    with progress.bar(n, desc="invert", unit="image", quiet=quiet) as pb:
        for i, im in enumerate(imgs):
            f = fit.fit(im)
            coef[i], beta[i], rec[i] = f["coefficients"], f["beta"], f["image"]
            h, _ = coarray.invert_channels(f["coefficients"], fit.B, starts=starts, seed=seed + i)
            chans[i] = h / np.linalg.norm(h)
            pb.update(1)
    crec = channel_images(chans, geometry, height=imgs.shape[1], width=imgs.shape[2])
    mag = np.abs(chans)
    return Inversion(coarray_ssim=ssim_images(rec, imgs), channel_ssim=ssim_images(crec, imgs),
                     coefficients=coef, beta=beta, channels=chans,
                     magnitude_ratio=mag.min(1) / np.maximum(mag.max(1), 1e-300), geometry=geometry,
                     coarray_images=rec if keep_images else None, channel_images=crec if keep_images else None)


def summary(inv: Inversion, *, stated: Geometry) -> dict:
    """The figures a person reads first (JSON-ready)."""
    g = inv.geometry
    best_row = max(inv.scan, key=lambda r: r["ssim_mean"]) if inv.scan else None
    out = {
        "images": int(len(inv.coarray_ssim)),
        "stated": {"frequency_hz": stated.frequency_hz, "pitch_m": stated.pitch_m,
                   "pitch_wavelengths": stated.pitch_wavelengths,
                   "elevation_start_deg": stated.elevation_start_deg},
        "used": {"frequency_hz": g.frequency_hz, "pitch_m": g.pitch_m, "pitch_wavelengths": g.pitch_wavelengths,
                 "elevation_start_deg": g.elevation_start_deg},
        "coarray_ssim": _stats(inv.coarray_ssim),
        "channel_ssim": _stats(inv.channel_ssim),
        "magnitude_ratio": _stats(inv.magnitude_ratio),
    }
    if best_row is not None:
        pw = best_row["pitch_wavelengths"]
        out["implied"] = {"elevation_start_deg": best_row["elevation_start_deg"], "pitch_wavelengths": pw,
                          "frequency_hz_at_stated_pitch": pw * SPEED_OF_LIGHT / stated.pitch_m,
                          "pitch_m_at_stated_frequency": pw * SPEED_OF_LIGHT / stated.frequency_hz,
                          "scan_ssim_mean": best_row["ssim_mean"]}
    return out


def _stats(x: np.ndarray) -> dict:
    x = np.asarray(x, np.float64)
    return {"mean": float(x.mean()), "median": float(np.median(x)), "min": float(x.min()),
            "p10": float(np.percentile(x, 10))}


def figure(images: np.ndarray, inv: Inversion, path: str | Path, *, rows: int = 4) -> Path:
    """PNG of ``rows`` images: measured, co-array re-render, channel re-render (each with its SSIM)."""
    from ..core import plots

    if inv.coarray_images is None or inv.channel_images is None:
        raise ConfigError("figure needs an inversion made with keep_images=True")
    n = len(images)
    pick = np.unique(np.linspace(0, n - 1, min(rows, n)).round().astype(int))
    fig, axes = plots.subplots(len(pick), 3, figsize=(12, 1.9 * len(pick) + 0.4), squeeze=False)
    for r, i in enumerate(pick):
        for c, (im, title) in enumerate([(images[i], f"spectrum {i + 1}"),
                                         (inv.coarray_images[i], f"co-array fit, SSIM {inv.coarray_ssim[i]:.3f}"),
                                         (inv.channel_images[i], f"rank-one channels, SSIM {inv.channel_ssim[i]:.3f}")]):
            plots.pas_panel(axes[r][c], im, title=title, left=c == 0, bottom=r == len(pick) - 1,
                            elevation_start_deg=inv.geometry.elevation_start_deg)
    return plots.save(fig, path)
