"""The loss over person positions (:class:`Query`): one person position's PAS and where they were
taken, compared with what the model renders with the person at a candidate position."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ...core.errors import ConfigError, DatasetError, ImageError
from ...data.views import downsample as block_means
from ...models.base import Views, render
from ...rf.bartlett_ref import normalize as minmax
from ...rf.grid import PAS_SHAPE
from ..predict import views_at
from .model import TwoStage

#: losses a localisation accepts
LOSSES = ("train", "ssim")
#: what the model's PAS are compared with (:class:`Query`): the query with the model's
#: background error cancelled by the empty room's PAS ("empty"), or the query as it is ("none")
REFERENCES = ("empty", "none")
#: views per render call
VIEWS_PER_CALL = 256


def read_pas(path: str | Path) -> np.ndarray:
    """PAS from a ``.npy`` file: float32 [K, 90, 360] (a single [90, 360] image is K = 1).

    Raises:
        DatasetError: the file is missing or not a NumPy array file; ImageError: an array of
        another shape, not numeric, or not finite.
    """
    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"PAS file {p} does not exist")
    try:
        a = np.load(p, allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        raise DatasetError(f"{p}: not a readable NumPy array file ({e})") from None
    if not np.issubdtype(a.dtype, np.number):
        raise ImageError(f"{p}: PAS must be numbers, got dtype {a.dtype}")
    return _as_pas(a, f"{p}: PAS")


def _image_losses(pred, gt, *, loss: str):
    """Per-image loss: ``pred`` and ``gt`` TensorXf [N, H, W] -> Float [N] (the training loss's
    terms per image, or 1 - SSIM)."""
    import drjit as dr

    from ...train import loss as L

    s = L.ssim(pred, gt)
    if loss == "ssim":
        return 1.0 - s
    n = pred.shape[1] * pred.shape[2]
    l1 = dr.block_sum(dr.abs(pred.array - gt.array), n) * (1.0 / n)
    return (1.0 - L.LAMBDA) * l1 + L.LAMBDA * (1.0 - s)


def _as_pas(pas: np.ndarray, what: str) -> np.ndarray:
    """float [K, 90, 360] or [90, 360] -> float32 [K, 90, 360] (ImageError naming ``what`` when
    misshapen or not finite)."""
    x = np.asarray(pas, np.float32)
    if x.ndim == 2:
        x = x[None]
    if x.ndim != 3 or x.shape[1:] != PAS_SHAPE or len(x) == 0:
        raise ImageError(f"{what} must be [K, {PAS_SHAPE[0]}, {PAS_SHAPE[1]}] or [{PAS_SHAPE[0]}, {PAS_SHAPE[1]}] "
                         f"(elevation x azimuth), got {np.shape(pas)}")
    bad = np.flatnonzero(~np.isfinite(x).all((1, 2)))
    if len(bad):
        raise ImageError(f"{what}: PAS {int(bad[0])} holds NaN or infinite values")
    return x


class Query:
    """One person position's PAS and where they were taken, ready to be compared with the model.

    Without ``empty`` the model's PAS with the person at ``p`` is compared with the query as it
    is (``reference = "none"``). With ``empty``, the empty room's measured PAS at the same
    positions, the compared prediction is that measurement plus the model's change (its PAS with
    the person at ``p`` less its background alone, both min-max normalised): the background's own
    error then cancels, and only what the person changes is fitted (``reference = "empty"``).

    Args:
        model: the two-stage model; pas: float [K, 90, 360] (or [90, 360]) raw or normalised PAS;
        positions: float [K, 3] (or [3]) the moving device's positions [m] (the array's in the
        moving-RX task, the transmitter's in the moving-TX task); loss: "train" or "ssim";
        downsample: block size d of the compared images (90 and 360 divisible by it).
        empty: None or float [K, 90, 360] the empty room's PAS at ``positions``.

    Raises:
        ImageError: PAS of the wrong shape or not finite.
        ConfigError: positions that do not match them, a bad loss or block size.
    """

    def __init__(self, model: TwoStage, pas: np.ndarray, positions: np.ndarray, *, loss: str = "train",
                 downsample: int = 2, empty: np.ndarray | None = None):
        import drjit as dr

        from ...core import backend as B

        x = _as_pas(pas, "PAS")
        q = np.asarray(positions, np.float64).reshape(-1, 3) if np.size(positions) % 3 == 0 else None
        if q is None or len(q) != len(x) or not np.isfinite(q).all():
            raise ConfigError(f"positions must be finite [K, 3] with one row per PAS (K = {len(x)}), got shape "
                              f"{np.shape(positions)}")
        if loss not in LOSSES:
            raise ConfigError(f"loss must be one of {LOSSES}, got {loss!r}")
        d = int(downsample)
        if d < 1 or PAS_SHAPE[0] % d or PAS_SHAPE[1] % d:
            raise ConfigError(f"downsample must divide 90 and 360, got {downsample}")
        self.model, self.loss, self.d = model, loss, d
        self.h, self.w = PAS_SHAPE[0] // d, PAS_SHAPE[1] // d
        self.positions = q
        self.k = len(q)
        self.target = minmax(block_means(minmax(x), d)).astype(np.float32)
        self._gt = B.TensorXf(self.target)
        self.reference = "none"
        self._offset = None
        if empty is not None:
            e = _as_pas(empty, "empty-room PAS")
            if len(e) != len(x):
                raise ImageError(f"the empty-room PAS must be one per query PAS ({len(x)}), got {len(e)}")
            ref = minmax(block_means(minmax(e), d)).astype(np.float32)
            with dr.suspend_grad():
                bg = render([model.background], self._views(np.zeros((1, 3))), height=self.h, width=self.w,
                            normalize=True)
                self._offset = B.TensorXf(B.Float(ref.ravel()) - bg.array, (self.k, self.h, self.w))
            self.reference = "empty"
        self.evaluations = 0
        self._prepared = None
        dr.eval(self._gt, self._offset)

    def _views(self, feet: np.ndarray) -> Views:
        """The views of every (candidate, query PAS) pair, candidate-major: C * K views."""
        c = len(feet)
        v = views_at(self.model.data, np.tile(self.positions, (c, 1)))
        ext = self.model.features(np.repeat(feet, self.k, axis=0))
        v.inputs = lambda field: ext
        return v

    def _tiled(self, t, c: int):
        """A TensorXf [K, H, W] repeated for C candidates: [C * K, H, W]."""
        import drjit as dr

        from ...core import backend as B

        n = self.k * self.h * self.w
        idx = dr.arange(B.UInt32, c * n) % dr.opaque(B.UInt32, n)
        return B.TensorXf(dr.gather(B.Float, t.array, idx), (c * self.k, self.h, self.w))

    def _candidate_losses(self, img, c: int):
        """Loss per candidate of the rendered images ``img`` TensorXf [C * K, H, W]: Float [C]."""
        import drjit as dr

        from ...core import backend as B

        if self._offset is not None:
            img = B.TensorXf(img.array + self._tiled(self._offset, c).array, tuple(img.shape))
        li = _image_losses(img, self._tiled(self._gt, c), loss=self.loss)
        return dr.block_sum(li, self.k) * (1.0 / self.k)

    def losses(self, xy: np.ndarray) -> np.ndarray:
        """The loss at feet positions ``xy`` (float [C, 2] m, at the region's height): float64 [C]."""
        import drjit as dr

        feet = np.concatenate([np.asarray(xy, np.float64).reshape(-1, 2),
                               np.full((len(xy), 1), self.model.feet_z)], axis=1)
        per = max(1, VIEWS_PER_CALL // self.k)
        out = np.empty(len(feet))
        fields = [self.model.background, self.model.person]
        for i in range(0, len(feet), per):
            part = feet[i:i + per]
            with dr.suspend_grad():
                img = render(fields, self._views(part), height=self.h, width=self.w, normalize=True)
                lc = self._candidate_losses(img, len(part))
            out[i:i + len(part)] = np.asarray(lc.numpy(), np.float64).reshape(len(part))
            self.evaluations += len(part)
        return out

    def loss_without_person(self) -> float:
        """The loss of the background alone (no person anywhere): what an estimate that explains
        nothing scores."""
        import drjit as dr

        with dr.suspend_grad():
            img = render([self.model.background], self._views(np.zeros((1, 3))), height=self.h, width=self.w,
                         normalize=True)
            return float(np.asarray(self._candidate_losses(img, 1).numpy()).ravel()[0])

    def loss_and_grad(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The loss and its gradient in ``(x, y)`` by Dr.Jit AD at feet positions ``xy`` (float [C,
        2] m): (float64 [C], float64 [C, 2]); needs :attr:`TwoStage.differentiable`."""
        import drjit as dr

        from ...core import backend as B

        m = self.model
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        c = len(xy)
        bg, person = m.background, m.person
        if self._prepared is None or self._prepared[0] != c:    # the views of C candidates, kept for every step
            views = self._views(np.concatenate([xy, np.full((c, 1), m.feet_z)], axis=1))
            with dr.suspend_grad():
                br, bi = bg.channels(views)
                dr.eval(br, bi)
            self._prepared = (c, views, br, bi, person.prepare(views))
        _, views, br, bi, prep = self._prepared
        p = B.Float(np.asarray(xy, np.float32).ravel())
        dr.enable_grad(p)
        view = dr.arange(B.UInt32, c * self.k) // dr.opaque(B.UInt32, self.k)
        cols = (dr.gather(B.Float, p, 2 * view), dr.gather(B.Float, p, 2 * view + 1),
                dr.full(B.Float, float(m.feet_z), c * self.k))
        pr, pi = person.channels_at(prep, cols)
        img = bg.read_out_channels(br + pr, bi + pi, frequency_hz=views.frequency_hz, height=self.h, width=self.w,
                                   normalize=True)
        lc = self._candidate_losses(img, c)
        dr.backward(dr.sum(lc))
        g = np.asarray(dr.grad(p).numpy(), np.float64).reshape(c, 2)
        self.evaluations += c
        return np.asarray(dr.detach(lc).numpy(), np.float64).reshape(c), g
