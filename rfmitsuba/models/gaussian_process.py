"""Gaussian-process field: the PAS as a Gaussian random field of the moving device's position.

Why: measured spectra change with position faster than any field of the stated positions at the
carrier can (docs/results/measured/diagnosis.md: channels 7 mm apart keep a coherence of 0.87,
a 920 MHz field at least 0.997), and the rest of their change is smooth out to half a metre. A
physical field fits such data at 0.85-0.90 SSIM; a lookup of the nearest training spectrum
carries what it cannot draw but not how the spectrum changes. This field is the statistical
model in between: every pixel of the normalised PAS is a Gaussian process of the position ``q``,
all pixels sharing one covariance,

    P(q) = m + sum_n a_n k(q, q_n),   a = (K + nu I)^-1 (Y - m),
    k(q, q') = exp(-|| (q - q') / l ||),

with ``Y`` [N, H*W] the training spectra, ``m`` their mean image (the prior mean), ``K`` the
kernel matrix of the training positions and ``l`` [3] one length scale per axis [m]. Far from
every training position the prediction falls back to the mean image; between close ones it
interpolates the spectra themselves, with weights that know how the spectra decorrelate.

The kernel is the exponential (Matern 1/2): a rough field, as the measured spectra are. The
hyperparameters are chosen in two steps, both on the conditioning spectra alone; there are no
options:

1. type-II maximum likelihood (:func:`fit_hyperparameters`) gives the nugget ``nu`` (the part of a
   spectrum no neighbour predicts, relative to the signal variance) and the length scales' ratios
   between the axes;
2. one common factor on the three length scales, among :data:`SCALE_FACTORS`, is chosen by the
   mean leave-one-out SSIM of the spectra (:func:`choose_scale_factor`; each spectrum predicted
   from all the others, in closed form).

Why the second step: the likelihood is ruled by the closest pairs of positions and the pixels'
squared error, and on measured spectra it picks length scales that let a prediction fall back to
the mean image before it has carried its neighbours' structure out to the distances a held-out
position lies at. On the measured NeRF2 RFID folder, under 17 held-out protocols (its published
split, six slabs of 20 % along x, y and z, the central 20 %, random 50 / 20 / 10 % training sets
on three seeds), the field beats the best of nearest neighbour, IDW-3 and the mean image in mean
SSIM in 16 of the 17 with the factor against 13 with the likelihood's scales alone, its worst
margin to that floor goes from -0.039 to -0.004 and its mean over the 17 from 0.765 to 0.768
(docs/results/measured/protocols.md). It costs on three slabs: the smallest y loses 0.026
(0.550 against 0.576; the floors reach at most 0.473 there), the largest y 0.007 and the smallest
x 0.006. The factors stop at 3: the leave-one-out SSIM is an interpolation score, and factors
up to 8 chose scales that extrapolate worse still (the slabs of the smallest x and y lost 0.022
and 0.049 against the likelihood's scales).

The field has no gradient training (:attr:`GaussianProcessField.closed_form`): the trainer
conditions it on the fitting spectra, validates it on the validation spectra, and conditions it
again on both (summary.json's ``conditioned_on``).

What it stores: the 5 fitted scalars (``l``, ``nu``, the signal variance ``s2``), the training
positions and the weights ``a`` [N, H, W] (as many numbers as the training spectra hold), and
``(K + nu I)^-1`` for the predictive standard deviation (:meth:`GaussianProcessField.predictive_sd`).
``num_parameters`` counts the fitted scalars; ``num_primitives`` the training spectra it is
conditioned on.

It takes the moving device's position as its only input: one fixed array and one fixed other
end per dataset (a NeRF2 folder, a moving-RX or moving-TX dataset of one state). It takes no
person inputs (Stage 2 refuses it).
"""
from __future__ import annotations

import json
from typing import ClassVar

import numpy as np

from ..core.errors import ConfigError, RunError
from ..rf.bartlett_ref import normalize as minmax
from .base import Field, Views, register

#: the largest number of conditioning spectra (weights [N, 90, 360] float32: 648 MB at 5000)
MAX_POSITIONS = 5000
#: the nugget's bounds, relative to the signal variance
NUGGET_BOUNDS = (1e-6, 1.0)
#: the common factors on the likelihood's length scales that :func:`choose_scale_factor` tries
#: (half octaves; the first of the best on a tie, 1 first)
SCALE_FACTORS = (1.0, 0.5, 0.7, 1.4, 2.0, 3.0)
#: the most conditioning spectra whose leave-one-out SSIM scores a factor (evenly spaced in their
#: order beyond it; the SSIMs, not the solves, cost most: 2000 spectra took 67 s on 2 cores)
LOO_SCORED = 1000


def exponential_kernel(a: np.ndarray, b: np.ndarray, length_scales: np.ndarray) -> np.ndarray:
    """``exp(-|| (a_i - b_j) / l ||)`` of positions a float [N, 3] and b float [M, 3] [m] with
    length scales l float [3] [m]: float64 [N, M]."""
    d = (np.asarray(a, np.float64)[:, None, :] - np.asarray(b, np.float64)[None, :, :]) / np.asarray(length_scales)
    return np.exp(-np.sqrt((d * d).sum(-1)))


def profile_nll(log_theta: np.ndarray, positions: np.ndarray, gram: np.ndarray, outputs: int,
                gradient: bool = False):
    """Negative log marginal likelihood per output, the signal variance profiled out.

    Args:
        log_theta: float [4] ``log`` of the three length scales [m] and of the nugget.
        positions: float [N, 3] [m]; gram: float [N, N] ``R R^T`` of the centred outputs R
            [N, outputs]; outputs: the number of outputs (pixels) sharing the kernel.
        gradient: also return the gradient with respect to ``log_theta``.

    Returns:
        ``N/2 log s2 + 1/2 log|C|`` with ``C = K + nu I`` and ``s2 = tr(C^-1 R R^T) / (N outputs)``
        (``inf`` where ``C`` is not positive definite); with ``gradient``, the pair (value, float
        [4] gradient), the gradient ``1/2 tr(W dC)`` with ``W = C^-1 - C^-1 R R^T C^-1 / (s2 outputs)``
        (zeros where the value is ``inf``).
    """
    ls, nu = np.exp(log_theta[:3]), float(np.exp(log_theta[3]))
    n = len(positions)
    k = exponential_kernel(positions, positions, ls)
    c = k + nu * np.eye(n)
    try:
        chol = np.linalg.cholesky(c)
    except np.linalg.LinAlgError:
        return (float("inf"), np.zeros(4)) if gradient else float("inf")
    from scipy.linalg import cho_solve

    prec = cho_solve((chol, True), np.eye(n))
    s2 = max(float(np.sum(prec * gram)) / (n * outputs), 1e-300)     # tr(C^-1 G), both symmetric
    value = 0.5 * n * np.log(s2) + float(np.log(np.diag(chol)).sum())
    if not gradient:
        return value
    w = prec - (prec @ gram @ prec) / (s2 * outputs)
    # dk / d log l_a = k (d_a / l_a)^2 / r, with r the scaled distance (0 on the diagonal)
    d2 = ((np.asarray(positions, np.float64)[:, None, :] - np.asarray(positions, np.float64)[None]) / ls) ** 2
    r = np.sqrt(d2.sum(-1))
    kr = np.divide(k, r, out=np.zeros_like(k), where=r > 0)
    grad = np.array([0.5 * float(np.sum(w * kr * d2[..., a])) for a in range(3)] + [0.5 * nu * float(np.trace(w))])
    return value, grad


def fit_hyperparameters(positions: np.ndarray, residuals: np.ndarray) -> dict:
    """Type-II maximum likelihood of the length scales and the nugget.

    Args:
        positions: float [N, 3] [m], at least two distinct ones.
        residuals: float [N, M] the outputs minus their prior mean.

    Returns:
        {"length_scales_m": [3], "nugget": float, "signal_variance": float, "nll": float}:
        the length scales lie between a tenth of the median nearest-neighbour distance and ten
        times the extent of the positions (an axis along which the positions do not vary gets
        the largest), the nugget within :data:`NUGGET_BOUNDS`.
    """
    from scipy.optimize import minimize

    x = np.asarray(positions, np.float64)
    r = np.asarray(residuals, np.float64)
    n, m = r.shape
    d = np.sqrt(((x[:, None] - x[None]) ** 2).sum(-1)) + np.diag(np.full(n, np.inf))
    near = float(np.median(d.min(1)))
    extent = float(np.linalg.norm(x.max(0) - x.min(0)))
    if not extent > 0:
        raise ConfigError("GaussianProcessField: the training positions are all the same point")
    lo, hi = max(0.1 * near, 1e-4 * extent), 10.0 * extent
    gram = r @ r.T
    bounds = [(np.log(lo), np.log(hi))] * 3 + [tuple(np.log(NUGGET_BOUNDS))]
    best = None
    for start in (0.1, 0.5):          # a short and a long start: the likelihood may have two basins
        x0 = np.r_[np.log(np.clip(start * extent, lo, hi)) * np.ones(3), np.log(1e-2)]
        o = minimize(profile_nll, x0, args=(x, gram, m, True), jac=True, method="L-BFGS-B", bounds=bounds)
        if best is None or o.fun < best.fun:
            best = o
    ls, nu = np.exp(best.x[:3]), float(np.exp(best.x[3]))
    c = exponential_kernel(x, x, ls) + nu * np.eye(n)
    s2 = float(np.trace(np.linalg.solve(c, gram))) / (n * m)
    return {"length_scales_m": [float(v) for v in ls], "nugget": nu, "signal_variance": s2, "nll": float(best.fun)}


def leave_one_out(images: np.ndarray, weights: np.ndarray, precision: np.ndarray) -> np.ndarray:
    """Leave-one-out posterior means of conditioning images float [N, P] with weights
    ``a = C^-1 (Y - m)`` float [N, P] and ``C^-1`` float [N, N]: ``Y_i - a_i / (C^-1)_ii``, the
    posterior mean at position i given every other image (same prior mean and kernel), float64 [N, P]."""
    return np.asarray(images, np.float64) - np.asarray(weights, np.float64) / np.diag(precision)[:, None]


def choose_scale_factor(positions: np.ndarray, images: np.ndarray, hyper: dict) -> dict:
    """The common factor on the likelihood's length scales with the best leave-one-out SSIM.

    Args:
        positions: float [N, 3] [m]; images: float [N, H, W] min-max normalised spectra.
        hyper: :func:`fit_hyperparameters`' result ("length_scales_m", "nugget").

    Returns:
        {"scale_factor": float, "loo_ssim_by_factor": {str(factor): mean SSIM}, "why": str}: each
        factor of :data:`SCALE_FACTORS` scores the mean SSIM of the min-max normalised leave-one-out
        predictions against the images (of at most :data:`LOO_SCORED` of them, each still predicted
        from all the others); on a grid smaller than SSIM's window the factor is 1.
    """
    from ..core.ssim import WINDOW, ssim_images

    x = np.asarray(positions, np.float64)
    y = np.asarray(images, np.float64)
    if min(y.shape[1:]) < WINDOW:
        return {"scale_factor": 1.0, "loo_ssim_by_factor": {},
                "why": f"images {y.shape[1]} x {y.shape[2]} are smaller than SSIM's window: the likelihood's scales"}
    flat = y.reshape(len(y), -1)
    res = flat - flat.mean(0)
    ls, nu = np.asarray(hyper["length_scales_m"], np.float64), float(hyper["nugget"])
    scored = np.unique(np.linspace(0, len(x) - 1, min(len(x), LOO_SCORED)).round().astype(int))
    scores = {}
    for factor in SCALE_FACTORS:
        prec = np.linalg.inv(exponential_kernel(x, x, factor * ls) + nu * np.eye(len(x)))[scored]
        loo = leave_one_out(flat[scored], prec @ res, prec[:, scored]).reshape(len(scored), *y.shape[1:])
        scores[factor] = float(np.mean(ssim_images(minmax(loo), y[scored])))
    best = max(SCALE_FACTORS, key=lambda f: scores[f])     # max keeps the first of equal scores
    return {"scale_factor": float(best), "loo_ssim_by_factor": {str(f): v for f, v in scores.items()},
            "why": f"the best leave-one-out SSIM of {len(scored)} of {len(x)} spectra ({scores[best]:.4f}; "
                   f"the likelihood's scales {scores[1.0]:.4f})"}


@register
class GaussianProcessField(Field):
    """The PAS as a Gaussian process of the moving device's position (module docstring).

    Args:
        height, width: the PAS grid it is conditioned on (90 x 360).

    Use :meth:`condition`; an unconditioned field renders nothing (RunError).
    """

    kind = "gaussian_process"
    family = "gaussian_process"
    format = "rfmitsuba-gaussian-process/1"
    #: conditioned once on the fitting spectra (:meth:`condition`), no gradient steps
    closed_form: ClassVar[bool] = True

    def __init__(self, *, height: int = 90, width: int = 360):
        self.shape = (int(height), int(width))
        self.positions = np.zeros((0, 3))
        self.mean = np.zeros(self.shape, np.float32)
        self.weights = np.zeros((0, *self.shape), np.float32)
        self.precision = np.zeros((0, 0))
        self.hyper: dict = {}

    @classmethod
    def for_training(cls, cfg, data, *, scene_xml=None, rng=None, extra_inputs: int = 0,
                     name: str = "bg") -> "GaussianProcessField":
        """An unconditioned field for the trainer (``cfg``, ``data``, ``scene_xml`` and ``rng`` are
        not needed: the field is chosen by its likelihood alone). Refuses extra inputs (Stage 2)."""
        if extra_inputs:
            raise ConfigError("model = 'gaussian_process' takes the moving device's position alone; "
                              "it cannot be a Stage-2 (person) field")
        f = cls()
        f.name = name
        return f

    # ---- conditioning ---------------------------------------------------------------------
    def condition(self, positions: np.ndarray, images: np.ndarray, *, hyper: dict | None = None) -> dict:
        """Condition the field on spectra at positions.

        Args:
            positions: float [N, 3] the moving device's positions [m].
            images: float [N, H, W] their min-max normalised PAS.
            hyper: the hyperparameters to use ({"length_scales_m", "nugget"}), or None to choose
                them (module docstring: :func:`fit_hyperparameters`, then :func:`choose_scale_factor`;
                the likelihood's own scales stay in "likelihood_length_scales_m").

        Returns:
            the hyperparameters used (also :attr:`hyper`).
        """
        x = np.asarray(positions, np.float64)
        y = np.asarray(images, np.float64)
        if x.ndim != 2 or x.shape[1] != 3 or y.shape[:1] != x.shape[:1] or y.shape[1:] != self.shape:
            raise ConfigError(f"GaussianProcessField.condition: positions {x.shape} and images {y.shape} "
                              f"do not match [N, 3] and [N, {self.shape[0]}, {self.shape[1]}]")
        if len(x) < 2:
            raise ConfigError(f"GaussianProcessField: needs at least 2 training spectra, got {len(x)}")
        if len(x) > MAX_POSITIONS:
            raise ConfigError(f"GaussianProcessField: {len(x)} training spectra, at most {MAX_POSITIONS} "
                              "(its weights hold one image per spectrum); set TrainConfig.max_train_positions")
        if not (np.isfinite(x).all() and np.isfinite(y).all()):
            raise ConfigError("GaussianProcessField: positions or images contain NaN or inf")
        flat = y.reshape(len(y), -1)
        mean = flat.mean(0)
        res = flat - mean
        if hyper is None:
            ml = fit_hyperparameters(x, res)
            chosen = choose_scale_factor(x, y, ml)
            hyper = {"length_scales_m": [chosen["scale_factor"] * v for v in ml["length_scales_m"]],
                     "nugget": ml["nugget"], "likelihood_length_scales_m": ml["length_scales_m"],
                     "likelihood_nll": ml["nll"], **chosen}
            # the signal variance is estimated below for the scales chosen
        ls, nu = np.asarray(hyper["length_scales_m"], np.float64), float(hyper["nugget"])
        c = exponential_kernel(x, x, ls) + nu * np.eye(len(x))
        prec = np.linalg.inv(c)
        self.positions = x
        self.mean = mean.reshape(self.shape).astype(np.float32)
        self.weights = (prec @ res).reshape(len(x), *self.shape).astype(np.float32)
        self.precision = prec
        s2 = hyper.get("signal_variance")
        if s2 is None:
            s2 = float(np.sum(res * (prec @ res))) / res.size
        self.hyper = {**hyper, "signal_variance": float(s2)}
        return dict(self.hyper)

    def _check(self) -> None:
        if not len(self.positions):
            raise RunError("GaussianProcessField: not conditioned on any spectra (call condition first)")

    def predict(self, positions: np.ndarray) -> np.ndarray:
        """The posterior mean PAS at positions float [K, 3] [m]: float32 [K, H, W] (raw: not
        min-max normalised; on the scale of the normalised training spectra)."""
        self._check()
        k = exponential_kernel(positions, self.positions, self.hyper["length_scales_m"])
        out = self.mean.reshape(1, -1) + k @ self.weights.reshape(len(self.positions), -1)
        return out.reshape(len(k), *self.shape).astype(np.float32)

    def predictive_sd(self, positions: np.ndarray) -> np.ndarray:
        """The posterior standard deviation of each pixel at positions float [K, 3] [m]: float64
        [K] (the same for every pixel, on the scale of the normalised spectra); it grows to
        :attr:`prior_sd` far from the training positions."""
        self._check()
        k = exponential_kernel(positions, self.positions, self.hyper["length_scales_m"])
        var = self.prior_sd ** 2 - self.hyper["signal_variance"] * np.einsum("kn,nm,km->k", k, self.precision, k)
        return np.sqrt(np.maximum(var, 0.0))

    @property
    def prior_sd(self) -> float:
        """The prior standard deviation of a pixel, ``sqrt(s2 (1 + nu))``: what
        :meth:`predictive_sd` grows to far from the data."""
        return float(np.sqrt(self.hyper["signal_variance"] * (1.0 + self.hyper["nugget"])))

    def loo_predictions(self) -> np.ndarray:
        """Leave-one-out posterior means at the conditioning positions: float32 [N, H, W] (each
        spectrum predicted from all the others, with the same hyperparameters; closed form)."""
        self._check()
        n = len(self.positions)
        w = self.weights.reshape(n, -1).astype(np.float64)
        c = exponential_kernel(self.positions, self.positions, self.hyper["length_scales_m"]) \
            + self.hyper["nugget"] * np.eye(n)
        y = self.mean.reshape(1, -1) + c @ w                                  # the training spectra: m + C a
        return leave_one_out(y, w, self.precision).reshape(n, *self.shape).astype(np.float32)

    # ---- Field protocol -------------------------------------------------------------------
    @property
    def num_primitives(self) -> int:
        return int(len(self.positions))

    @property
    def num_parameters(self) -> int:
        return 5

    @property
    def network_parameters(self) -> int:
        return 0

    def parameters(self) -> dict:
        return {}

    def assign(self, values: dict) -> None:
        if values:
            raise ConfigError(f"GaussianProcessField has no trainable parameters, got {sorted(values)}")

    def freeze(self) -> None:
        self.frozen = True

    def state_dict(self) -> dict:
        meta = {"format": self.format, "kind": self.kind, "shape": list(self.shape), "hyper": self.hyper,
                "name": self.name}
        return {"meta": np.array(json.dumps(meta)), "positions": self.positions, "mean": self.mean,
                "weights": self.weights, "precision": self.precision}

    def load_state_dict(self, state: dict) -> None:
        for k in ("positions", "mean", "weights", "precision"):
            if k not in state:
                raise RunError(f"GaussianProcessField state lacks {k!r}")
        x = np.asarray(state["positions"], np.float64)
        n = len(x)
        want = {"positions": (n, 3), "mean": self.shape, "weights": (n, *self.shape), "precision": (n, n)}
        for k, shape in want.items():
            v = np.asarray(state[k])
            if v.shape != shape or not np.isfinite(v).all():
                raise RunError(f"GaussianProcessField state {k!r}: expected {shape} finite values, got {v.shape}")
        self.positions = x
        self.mean = np.asarray(state["mean"], np.float32)
        self.weights = np.asarray(state["weights"], np.float32)
        self.precision = np.asarray(state["precision"], np.float64)

    @classmethod
    def from_state_dict(cls, state: dict) -> "GaussianProcessField":
        meta = json.loads(str(state["meta"]))
        f = cls(height=meta["shape"][0], width=meta["shape"][1])
        f.hyper = dict(meta.get("hyper") or {})
        f.name = meta.get("name", "bg")
        if not {"length_scales_m", "nugget", "signal_variance"} <= set(f.hyper):
            raise RunError("GaussianProcessField state: 'meta' lacks its hyperparameters")
        f.load_state_dict(state)
        return f

    @classmethod
    def render_family(cls, fields: list, views: Views, *, height: int, width: int, normalize: bool):
        """The posterior mean PAS at the views' moving-device positions: ``TensorXf`` [B, height,
        width] (block means where the grid is coarser than the conditioning one), min-max
        normalised per image when ``normalize``. One Gaussian-process field at a time."""
        from ..core import backend as B

        if len(fields) != 1:
            raise ConfigError(f"a Gaussian-process field renders alone, got {len(fields)} fields")
        f = fields[0]
        img = f.predict(views.antenna_pos)
        h0, w0 = f.shape
        if (height, width) != (h0, w0):
            if h0 % height or w0 % width:
                raise ConfigError(f"GaussianProcessField: cannot render {height} x {width} from its {h0} x {w0} grid")
            img = img.reshape(len(img), height, h0 // height, width, w0 // width).mean((2, 4))
        if normalize:
            img = minmax(img)
        B.ensure()
        return B.TensorXf(np.ascontiguousarray(img, np.float32))

    def export_ply(self, folder, *, views: Views) -> list:
        """Nothing to export: the field has no primitives in space."""
        return []
