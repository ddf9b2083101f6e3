"""The co-array form of a Bartlett image, and its inversion to element channels.

For the 4 x 4 array at pitch ``d`` the squared Bartlett spectrum of channels ``h`` [16] is a
two-dimensional Fourier series over the array's co-array, the 7 x 7 element-offset lags
``l = r_m - r_n`` (in pitches)::

    P(e)^2 = | sum_m conj(v_m(e)) h_m |^2 / M^2 = sum_l C_l exp(-j k d (l_x u + l_y v)) / M^2,
    C_l = sum_{m - n = l} h_m conj(h_n),        C_{-l} = conj(C_l),

with ``u = cos(el) cos(az)``, ``v = cos(el) sin(az)`` (array frame). A real image therefore
holds at most 49 real numbers: ``C_0`` and the real and imaginary parts of the 24 lags with
``l > 0``. A min-max normalised image ``I`` is ``(P - lo) / (hi - lo)``, so ``P`` is
``alpha (I + beta)`` for unknown ``alpha > 0`` and ``beta >= 0``: :func:`fit_coarray` solves the
linear least squares of ``(I + beta)^2`` on the 49 basis images for every ``beta`` of a grid
and keeps the smallest residual.

Where an image is the Bartlett image of one set of channels (rank one), :func:`invert_channels`
recovers those channels from the coefficients, up to a common complex factor and the twin
``h'_m = conj(h_{M-1-m})`` (the element mirrored through the array centre, conjugated), which
draws the same image on a centro-symmetric array.

Grids: ``elevation_start_deg`` is the elevation [degrees] of row 0. The project's PAS grid
(:mod:`rfmitsuba.rf.grid`) starts at 1 degree; the images of published NeRF2 folders start at 0
degrees (:data:`NERF2_ELEVATION_START_DEG`; measured: the co-array fit of the published
``data_test200`` images is 0.998 mean SSIM with row 0 at 0 degrees, 0.988 at 1 degree).
"""
from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError
from .array import COLS, ROWS, SPEED_OF_LIGHT
from .grid import directions

#: elevation [degrees] of row 0 in the images of a published NeRF2 folder
NERF2_ELEVATION_START_DEG = 0.0


def lags(*, rows: int = ROWS, cols: int = COLS) -> np.ndarray:
    """The positive half of the co-array: int64 [L, 2] lags ``(l_x, l_y)`` [pitches] with
    ``(l_x, l_y) > (0, 0)`` in lexicographic order of ``(l_y, l_x)`` (24 for the 4 x 4 array)."""
    out = [(lx, ly) for ly in range(0, rows) for lx in range(-(cols - 1), cols) if (ly, lx) > (0, 0)]
    return np.asarray(out, np.int64)


def look_directions(height: int = 90, width: int = 360, *, elevation_start_deg: float = 1.0) -> np.ndarray:
    """Unit look directions of an image grid: float64 [height * width, 3], array frame.

    The PAS grid of :func:`rfmitsuba.rf.grid.directions` with row 0 of the 1-degree grid at
    ``elevation_start_deg`` [degrees]: at 90 x 360 row ``i`` is elevation ``elevation_start_deg + i``,
    column ``j`` azimuth ``j`` [degrees]."""
    if height < 1 or width < 1 or 90 % height or 360 % width or width * 90 != height * 360:
        raise ConfigError(f"an image grid must be 90/d x 360/d, got {height} x {width}")
    return directions(resolution_deg=90 // height, elevation_start_deg=elevation_start_deg).reshape(-1, 3)


def basis(directions: np.ndarray, *, frequency_hz: float, pitch_m: float) -> np.ndarray:
    """The 49 real basis images of the squared spectrum: float64 [P, 1 + 2 L].

    Column 0 is 1; columns ``1 + 2 i`` and ``2 + 2 i`` are ``cos`` and ``sin`` of the phase
    ``k d (l_x u + l_y v)`` of lag ``i`` of :func:`lags`.

    Args:
        directions: float [P, 3] unit look directions (array frame).
        frequency_hz: carrier [Hz]; pitch_m: element pitch [m].
    """
    if not (frequency_hz > 0 and pitch_m > 0):
        raise ConfigError(f"frequency_hz and pitch_m must be positive, got {frequency_hz!r}, {pitch_m!r}")
    d = np.asarray(directions, np.float64)
    kd = 2 * np.pi * frequency_hz / SPEED_OF_LIGHT * pitch_m
    ph = kd * (d[:, :1] * lags()[:, 0] + d[:, 1:2] * lags()[:, 1])        # [P, L]
    out = np.empty((len(d), 1 + 2 * ph.shape[1]))
    out[:, 0] = 1.0
    out[:, 1::2], out[:, 2::2] = np.cos(ph), np.sin(ph)
    return out


def coefficients_to_lags(c: np.ndarray) -> np.ndarray:
    """Real coefficients float [..., 49] of :func:`basis` -> complex ``C_l`` [..., 25]: ``C_0``
    then the 24 lags of :func:`lags` (``cos`` takes ``2 Re C_l``, ``sin`` ``2 Im C_l``)."""
    c = np.asarray(c, np.float64)
    return np.concatenate([c[..., :1] + 0j, (c[..., 1::2] + 1j * c[..., 2::2]) / 2], -1)


def _lag_matrix() -> np.ndarray:
    """float64 [25, 256]: row ``l`` sums the entries ``(m, n)`` (flattened ``m * 16 + n``) of an
    outer product ``h h^H`` with ``r_m - r_n`` = lag ``l`` (``C_0`` first, then :func:`lags`)."""
    n = COLS * ROWS
    col, row = np.arange(n) % COLS, np.arange(n) // COLS
    dx, dy = (col[:, None] - col[None, :]).ravel(), (row[:, None] - row[None, :]).ravel()
    keys = [(0, 0)] + [tuple(map(int, l)) for l in lags()]
    return np.stack([((dx == lx) & (dy == ly)).astype(np.float64) for lx, ly in keys])


_LAGS_OF_OUTER = _lag_matrix()


def channel_lags(h: np.ndarray) -> np.ndarray:
    """``C_l = sum_{m - n = l} h_m conj(h_n)`` of channels complex [..., 16]: complex [..., 25]
    (``C_0`` then the lags of :func:`lags`)."""
    h = np.asarray(h, np.complex128)
    outer = (h[..., :, None] * np.conj(h[..., None, :])).reshape(*h.shape[:-1], -1)
    return outer @ _LAGS_OF_OUTER.T


class CoarrayFit:
    """Least-squares co-array fits of normalised images on one grid (the basis factorised once).

    Args:
        frequency_hz: carrier [Hz]; pitch_m: element pitch [m].
        height, width: image grid; elevation_start_deg: elevation of row 0 [degrees].
        betas: the offsets ``beta`` tried (default 0..2 in steps of 0.01).
    """

    def __init__(self, *, frequency_hz: float, pitch_m: float, height: int = 90, width: int = 360,
                 elevation_start_deg: float = 1.0, betas: np.ndarray | None = None):
        self.frequency_hz, self.pitch_m = float(frequency_hz), float(pitch_m)
        self.shape = (height, width)
        self.elevation_start_deg = float(elevation_start_deg)
        self.B = basis(look_directions(height, width, elevation_start_deg=elevation_start_deg),
                       frequency_hz=frequency_hz, pitch_m=pitch_m)
        self.Q, self.Rfac = np.linalg.qr(self.B)
        self.betas = np.arange(0.0, 2.0001, 0.01) if betas is None else np.asarray(betas, np.float64)

    def fit(self, image: np.ndarray) -> dict:
        """One image float [H, W] (min-max normalised) -> {"coefficients": float64 [49],
        "beta": offset, "residual": relative residual of the squared image, "image": the
        re-rendered normalised image float64 [H, W]}."""
        img = np.asarray(image, np.float64)
        if img.shape != self.shape:
            raise ConfigError(f"image is {img.shape}, the fit's grid is {self.shape}")
        if not np.isfinite(img).all():
            raise ConfigError("image contains NaN or inf")
        y0, y1, y2 = img.ravel() ** 2, 2 * img.ravel(), np.ones(img.size)
        # (I + b)^2 = y0 + b y1 + b^2 y2: the residual after projection is quadratic in b
        r = [y - self.Q @ (self.Q.T @ y) for y in (y0, y1, y2)]
        b = self.betas
        res = np.linalg.norm(r[0][None] + b[:, None] * r[1][None] + (b ** 2)[:, None] * r[2][None], axis=1)
        tot = np.linalg.norm(y0[None] + b[:, None] * y1[None] + (b ** 2)[:, None] * y2[None], axis=1)
        i = int(np.argmin(res / tot))
        beta = float(b[i])
        if len(b) > 1:       # refine between the grid's neighbours: the true offset makes the residual 0
            from scipy.optimize import minimize_scalar

            lo_b, hi_b = float(b[max(i - 1, 0)]), float(b[min(i + 1, len(b) - 1)])

            def rel(x):
                return (np.linalg.norm(r[0] + x * r[1] + x * x * r[2])
                        / np.linalg.norm(y0 + x * y1 + x * x * y2))

            o = minimize_scalar(rel, bounds=(lo_b, hi_b), method="bounded", options={"xatol": 1e-6})
            if o.fun < res[i] / tot[i]:
                beta = float(o.x)
        res_i = rel(beta) if len(b) > 1 else float(res[i] / tot[i])
        y = y0 + beta * y1 + beta ** 2 * y2
        c = np.linalg.solve(self.Rfac, self.Q.T @ y)
        return {"coefficients": c, "beta": beta, "residual": float(res_i),
                "image": render_coefficients(c, self.B, self.shape)}


def render_coefficients(c: np.ndarray, B: np.ndarray, shape: tuple) -> np.ndarray:
    """The normalised amplitude image of co-array coefficients: ``sqrt(max(B c, 0))``, min-max
    normalised, float64 ``shape``."""
    p = np.sqrt(np.maximum(B @ np.asarray(c, np.float64), 0.0)).reshape(shape)
    span = p.max() - p.min()
    return (p - p.min()) / span if span > 0 else np.zeros(shape)


def invert_channels(c: np.ndarray, B: np.ndarray, *, starts: int = 12, seed: int = 0,
                    tol: float = 1e-5, phase_only: bool = False) -> tuple[np.ndarray, float]:
    """Rank-one channels of co-array coefficients: (h complex128 [16] with ``h_0`` real and
    positive, relative residual).

    Minimises ``|| B (c(h) - c) ||`` over ``h``, with ``c(h)`` the coefficients of ``h``
    (:func:`channel_lags`), from ``starts`` seeded starts (the first the leading eigenvector of
    the co-array's averaged covariance); it stops early once the relative residual is below
    ``tol``. ``h`` is found up to the twin ``conj(h[::-1])``. ``phase_only`` fits unit-modulus
    channels times one common magnitude (the read-out of ``h / |h|``): its residual against the
    free fit's says whether a phase-only read-out can have drawn the image.
    """
    from scipy.linalg import cholesky
    from scipy.optimize import least_squares

    c = np.asarray(c, np.float64)
    L = cholesky(B.T @ B / len(B), lower=False)           # ||B x||^2 / P = ||L x||^2
    col, row = np.arange(16) % COLS, np.arange(16) // COLS
    lag_index = {(0, 0): 0, **{(int(lx), int(ly)): i + 1 for i, (lx, ly) in enumerate(lags())}}
    C = coefficients_to_lags(c)

    def entry(i, j):
        lx, ly = int(col[i] - col[j]), int(row[i] - row[j])
        n = (COLS - abs(lx)) * (ROWS - abs(ly))
        if (lx, ly) in lag_index:
            return C[lag_index[(lx, ly)]] / n
        return np.conj(C[lag_index[(-lx, -ly)]]) / n

    R = np.array([[entry(i, j) for j in range(16)] for i in range(16)])
    w, V = np.linalg.eigh((R + R.conj().T) / 2)
    x_eig = np.sqrt(max(w[-1], 1e-12)) * V[:, -1]

    def coeffs(h):
        cl = channel_lags(h)
        out = np.empty(49)
        out[0] = cl[0].real
        out[1::2], out[2::2] = 2 * cl[1:].real, 2 * cl[1:].imag
        return out

    scale = np.linalg.norm(L @ c) or 1.0

    def channels(x):
        if phase_only:
            return x[16] * np.exp(1j * x[:16])
        return x[:16] + 1j * x[16:]

    def resid(x):
        return L @ (coeffs(channels(x)) - c) / scale

    rng = np.random.default_rng(seed)
    best = None
    for s in range(max(int(starts), 1)):
        h0 = x_eig if s == 0 else (rng.normal(size=16) + 1j * rng.normal(size=16)) * np.sqrt(abs(C[0].real) / 16)
        x0 = np.r_[np.angle(h0), np.sqrt(abs(C[0].real) / 16)] if phase_only else np.r_[h0.real, h0.imag]
        o = least_squares(resid, x0, method="lm", max_nfev=2000)
        if best is None or o.cost < best.cost:
            best = o
        if np.sqrt(2 * best.cost) < tol:
            break
    h = channels(best.x)
    h = h * np.exp(-1j * np.angle(h[0]))
    return h, float(np.sqrt(2 * best.cost))


def twin(h: np.ndarray) -> np.ndarray:
    """The twin channels ``conj(h[::-1])`` [..., 16]: the same Bartlett image on the 4 x 4 array."""
    return np.conj(np.asarray(h)[..., ::-1])


def channel_error(h: np.ndarray, truth: np.ndarray) -> float:
    """Relative error of channels complex [16] against ``truth`` [16], minimised over a common
    complex factor and the twin: ``min || a h' - truth || / || truth ||``."""
    t = np.asarray(truth, np.complex128)
    best = np.inf
    for cand in (np.asarray(h, np.complex128), twin(h)):
        a = np.vdot(cand, t) / np.vdot(cand, cand)
        best = min(best, float(np.linalg.norm(a * cand - t) / np.linalg.norm(t)))
    return best
