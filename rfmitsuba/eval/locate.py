"""Device-free localisation: where a person stands, from the PAS they change, with a trained
two-stage model (a Stage-2 person field on its frozen Stage-1 background).

With the background and the person field fixed, the PAS the model renders at the query's antenna
positions is a function of the person's feet position ``p`` alone. :func:`locate` minimises a
loss between rendered and given PAS over ``p``:

1. **Where the person can be** (:class:`SearchRegion`): the box of the training walk grown by
   :data:`WALK_MARGIN_M` (``region="walk"``, the default: a person field is trained along the
   walk only, and far from it it may render a person who changes nothing, which an unlikely
   query then matches best), or the known room's whole free space (``region="room"``); in a
   known room, less what is within :data:`CLEARANCE_M` of the walls or of the footprint of
   furniture at body height (the walk of :func:`rfmitsuba.sim.person.walk` keeps 0.25 m). The
   height is the training walk's feet height (its median z), as in training.
2. **Coarse grid**: the loss at every free point of a grid of ``grid_m`` spacing; the ``starts``
   best points at least two grid steps apart start the descent.
3. **Descent**: for a person field whose channels are differentiable in the position
   (:meth:`rfmitsuba.models.coherent_gaussians_person.CoherentGaussianPersonField.channels_at`),
   Adam on ``(x, y)`` with Dr.Jit AD (``steps`` steps, step size ``lr_m`` decaying to a tenth);
   otherwise (the splat person field: its features enter its networks from the host) a bounded
   Nelder-Mead search of SciPy from each start (at most ``4 * steps`` losses each). A step that
   leaves the free space is not taken.
4. **Fringe hop and polish**: a coherent model's loss has a local minimum about every half
   wavelength (the person's scattered path changes phase as it moves), and a descent stops in
   the one nearest its start; a 5 x 5 grid of a quarter wavelength around each descent's end
   (:func:`_hop`) picks the best neighbouring one, and a third as many descent steps (a third
   of the step size) polish it. The estimate is the lowest loss met.

The loss is the training loss of :mod:`rfmitsuba.train.loss` (``0.8 L1 + 0.2 (1 - SSIM)`` on
min-max normalised PAS, ``loss="train"``) or ``1 - SSIM`` (``loss="ssim"``), on ``d x d``
block means of the PAS (``downsample``; 2 = 45 x 180, the coherent Gaussian field's training
images), averaged over the query's PAS. A query is one PAS or several of one person position
seen from several antenna positions (one frame of a dataset: every array position with the
person at one place).

What is compared with the query (:class:`Query`): the model's PAS with the person at ``p``
(``empty=None``, reference "none"), or, given the empty room's measured PAS at the same
positions, that measurement plus the model's change (its PAS with the person at ``p`` less its
background alone; reference "empty"). The second cancels the background's own error, which is
often larger than what the person changes and which the search otherwise spends the person
field on (:func:`evaluate_locate` uses it by default: a deployment that knows the room measures
it empty once).

Neither person field takes the person's heading (their inputs are the feet position and its
encoding), so nothing is assumed about it: the model renders the person it learned, over the
headings of the training walk.

:func:`evaluate_locate` scores the held-out walk positions of a run's dataset (its person test
split) for every Ours job of a comparison (one per seed), beside two floors that need no model:

* **fingerprint** - the person position of the training walk state whose measured PAS at the
  query's antenna positions are most similar (highest mean SSIM, Dr.Jit's float32 SSIM of
  :func:`rfmitsuba.train.loss.ssim`, skimage's definition, at 90 x 360);
* **centre** - the training walk's centroid (and, in a known room, the room's centre).

It also says where the model fails (:func:`failure_proxies`): error against the distance from
the array and from the transmitter, against whether the person blocks direct paths and whether
furniture hides them from the transmitter; and why (the model's loss at the true position against
its estimate's and against the background alone). :func:`plot_locate` draws true against estimated positions on the room's top
view; :func:`report_markdown` the tables.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import ConfigError, DatasetError, ImageError, RunError
from ..data.samples import SampleData, person_features
from ..data.views import downsample as block_means
from ..models.base import Field, Views, load_field, render
from ..rf.bartlett_ref import normalize as minmax
from ..rf.grid import PAS_SHAPE
from .predict import views_at

#: horizontal clearance [m] of the feet from walls and from furniture footprints at body height
#: in the search region of a known room (the walk keeps 0.25 m; a little less, so that the
#: region holds every walk position)
CLEARANCE_M = 0.2
#: how far [m] the walk search region reaches past the training walk's box
WALK_MARGIN_M = 0.5
#: height [m] of the body column that must be clear of furniture (rfmitsuba.sim.person.HEIGHT)
BODY_HEIGHT_M = 1.7
#: radius [m] of the body for the failure proxies (half of rfmitsuba.sim.person.WIDTH)
BODY_RADIUS_M = 0.225
#: height above the feet [m] of the point the shadow proxy looks at (the chest)
CHEST_M = 1.2
#: losses a localisation accepts
LOSSES = ("train", "ssim")
#: search regions (:meth:`SearchRegion.of`)
REGIONS = ("walk", "room")
#: what the model's PAS are compared with (:class:`Query`): the query with the model's
#: background error cancelled by the empty room's PAS ("empty"), or the query as it is ("none")
REFERENCES = ("empty", "none")
#: views per render call
VIEWS_PER_CALL = 256
#: an estimate this far [cm] from the truth counts as a miss in the report's account of why
MISS_CM = 100.0


# ------------------------------------------------------------------------ the model
@dataclass
class TwoStage:
    """A trained two-stage model opened for localisation.

    background: the frozen Stage-1 field; person: the frozen Stage-2 person field
    (``Field.person``); data: the dataset the job trained on, as samples of every state
    (:class:`~rfmitsuba.data.samples.SampleData`); feet_z: the feet height [m] of the training
    walk (median); walk: float64 [H, 3] the training walk's feet positions [m]; job: the job folder.
    """

    background: Field
    person: Field
    data: SampleData
    feet_z: float
    walk: np.ndarray
    job: Path

    @property
    def differentiable(self) -> bool:
        """The person field's channels are differentiable in the person's position (AD descent)."""
        return hasattr(self.person, "channels_at") and self.background.family == "coherent_gaussians"

    def features(self, feet: np.ndarray) -> np.ndarray:
        """The person field's extra inputs for feet positions float [N, 3] m: float32 [N, F + 3]
        (features of :func:`~rfmitsuba.data.samples.person_features` on the training box, then the
        position), as :meth:`~rfmitsuba.data.samples.SampleData.features` gives them in training."""
        h = np.asarray(feet, np.float64).reshape(-1, 3)
        f = person_features(h, self.data.box, octaves=self.person.feature_octaves)
        return np.concatenate([f, h.astype(np.float32)], axis=1)


def open_two_stage(job: str | Path) -> TwoStage:
    """Open an Ours job folder (``stage1.json`` naming its Stage-1 run, ``stage2/final/field.npz``).

    Raises:
        RunError: not a two-stage job (a Stage-1 run, another method's job, an unfinished job,
            a Stage-2 field that is not a person field, or a dataset that is gone).
    """
    jd = Path(job)
    if not (jd / "stage1.json").is_file():
        _refuse(jd)
    s2 = jd / "stage2"
    if not (s2 / "final" / "field.npz").is_file() or not (s2 / "run.json").is_file():
        raise RunError(f"{jd}: Stage 2 has not finished (no stage2/final/field.npz); run the comparison again to "
                       "finish it")
    try:
        stage1 = Path(json.loads((jd / "stage1.json").read_text())["stage1_dir"])
        dataset = Path(json.loads((s2 / "run.json").read_text())["dataset"])
    except (json.JSONDecodeError, KeyError, TypeError) as e:
        raise RunError(f"{jd}: stage1.json or stage2/run.json is malformed ({type(e).__name__}: {e})") from None
    person = load_field(s2 / "final" / "field.npz")
    if not person.person:
        raise RunError(f"{jd}: the Stage-2 field is a {type(person).__name__}, not a person field")
    background = load_field(stage1 / "final" / "field.npz")
    background.freeze()
    person.freeze()
    if not dataset.is_dir():
        raise RunError(f"{jd}: its dataset {dataset} does not exist any more")
    data = SampleData.open_samples(dataset, states="all")
    walk = data.person_pos[np.isin(data.states, np.asarray(data.split.person_train) + 1) & (data.antennas == 0)]
    if len(walk) == 0:
        raise DatasetError(f"{dataset}: no training walk positions")
    return TwoStage(background=background, person=person, data=data, feet_z=float(np.median(walk[:, 2])),
                    walk=walk, job=jd)


def _refuse(jd: Path) -> None:
    """RunError: ``jd`` is not a two-stage job, naming what it is."""
    what = ("a single-field run (config.toml, no stage1.json)" if (jd / "config.toml").is_file()
            else "another method's job (train/, no stage1.json)" if (jd / "train").is_dir() else "not a job folder")
    raise RunError(f"{jd} is not a two-stage job: {what}; localisation needs an Ours job (a Stage-2 person "
                   "field on a frozen Stage-1 background), e.g. COMPARE/seed0/ours of `rfmitsuba compare "
                   "--methods baseline,ours`")


def job_folders(run: str | Path) -> list[tuple[str, Path]]:
    """The Ours jobs of ``run``: (label, folder) of the job itself (label its folder name), of a
    comparison's ``seed<k>/ours`` (label ``seed<k>``), or of a demo folder's ``ours``.

    Raises:
        RunError: none found, naming what was looked for.
    """
    r = Path(run)
    if not r.is_dir():
        raise RunError(f"{r} does not exist")
    if (r / "stage1.json").is_file() or (r / "stage2").is_dir():
        return [(r.name, r)]
    seeds = sorted((p for p in r.glob("seed*/ours") if (p / "stage1.json").is_file()),
                   key=lambda p: int(p.parent.name[4:]) if p.parent.name[4:].isdigit() else 0)
    if seeds:
        return [(p.parent.name, p) for p in seeds]
    if (r / "ours" / "stage1.json").is_file():
        return [("ours", r / "ours")]
    if (r / "config.toml").is_file() or (r / "train").is_dir():
        _refuse(r)
    raise RunError(f"{r} holds no two-stage job (stage1.json; seed<k>/ours/ of a comparison; ours/ of a demo): "
                   "train one with `rfmitsuba compare DATASET --methods baseline,ours`, then locate with it")


# ------------------------------------------------------------------------ where the person can be
@dataclass
class SearchRegion:
    """Where the feet may be: the box ``lo``..``hi`` (float64 [2] each, x and y [m]) at height
    ``z`` [m], less what ``geometry`` (a :class:`~rfmitsuba.sim.geometry.RoomGeometry`, or None)
    says is not free. ``kind``: "room" or "walk"."""

    lo: np.ndarray
    hi: np.ndarray
    z: float
    geometry: object = None
    kind: str = "walk"

    @classmethod
    def of(cls, model: TwoStage, *, region: str = "walk") -> "SearchRegion":
        """The region of ``model``: "walk" (the training walk's box grown by :data:`WALK_MARGIN_M`,
        less the walls' and furniture's margins where the room is known) or "room" (the known
        room's free space)."""
        if region not in REGIONS:
            raise ConfigError(f"region must be one of {REGIONS}, got {region!r}")
        geometry = None
        if model.data.scene_xml is not None:
            from ..sim.geometry import RoomGeometry

            geometry = RoomGeometry.from_xml(model.data.scene_xml)
        if region == "room" and geometry is None:
            raise ConfigError(f"{model.data.path} names no room, so its free space is unknown: use region 'walk'")
        if region == "room":
            lo, hi = geometry.bounds
            lo, hi = lo[:2] + CLEARANCE_M, hi[:2] - CLEARANCE_M
        else:
            lo, hi = model.walk[:, :2].min(0) - WALK_MARGIN_M, model.walk[:, :2].max(0) + WALK_MARGIN_M
            if geometry is not None:
                rlo, rhi = geometry.bounds
                lo, hi = np.maximum(lo, rlo[:2] + CLEARANCE_M), np.minimum(hi, rhi[:2] - CLEARANCE_M)
        return cls(lo=np.asarray(lo, np.float64), hi=np.asarray(hi, np.float64), z=model.feet_z, geometry=geometry,
                   kind=region)

    def feet(self, xy: np.ndarray) -> np.ndarray:
        """float [N, 2] -> feet positions float64 [N, 3] at the region's height."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        return np.concatenate([xy, np.full((len(xy), 1), self.z)], axis=1)

    def free(self, xy: np.ndarray) -> np.ndarray:
        """Whether each point float [N, 2] is in the region: bool [N]."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        ok = np.isfinite(xy).all(1) & (xy >= self.lo - 1e-9).all(1) & (xy <= self.hi + 1e-9).all(1)
        if self.geometry is not None and ok.any():
            ok[ok] = self.geometry.free_mask(self.feet(xy[ok]), clearance=CLEARANCE_M, body_height=BODY_HEIGHT_M)
        return ok

    def grid(self, step: float) -> np.ndarray:
        """The free points of a grid of ``step`` [m] spacing centred in the box: float64 [M, 2]."""
        if not step > 0:
            raise ConfigError(f"grid spacing must be > 0 m, got {step}")
        axes = []
        for a in range(2):
            n = max(1, int(np.floor((self.hi[a] - self.lo[a]) / step)) + 1)
            off = 0.5 * ((self.hi[a] - self.lo[a]) - (n - 1) * step)
            axes.append(self.lo[a] + off + step * np.arange(n))
        xy = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 2)
        xy = xy[self.free(xy)]
        if len(xy) == 0:
            raise ConfigError(f"the search region ({self.kind}) holds no free grid point at {step} m spacing")
        return xy


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


# ------------------------------------------------------------------------ the loss over person positions
def _image_losses(pred, gt, *, loss: str):
    """Per-image loss: ``pred`` and ``gt`` TensorXf [N, H, W] -> Float [N] (the training loss's
    terms per image, or 1 - SSIM)."""
    import drjit as dr

    from ..train import loss as L

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

        from ..core import backend as B

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

        from ..core import backend as B

        n = self.k * self.h * self.w
        idx = dr.arange(B.UInt32, c * n) % dr.opaque(B.UInt32, n)
        return B.TensorXf(dr.gather(B.Float, t.array, idx), (c * self.k, self.h, self.w))

    def _candidate_losses(self, img, c: int):
        """Loss per candidate of the rendered images ``img`` TensorXf [C * K, H, W]: Float [C]."""
        import drjit as dr

        from ..core import backend as B

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

        from ..core import backend as B

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


# ------------------------------------------------------------------------ the search
def _spread_starts(xy: np.ndarray, losses: np.ndarray, count: int, min_dist: float) -> np.ndarray:
    """Indices of the ``count`` lowest losses whose points are at least ``min_dist`` apart (greedy)."""
    order = np.argsort(losses, kind="stable")
    pick: list[int] = []
    for i in order:
        if all(np.hypot(*(xy[i] - xy[j])) >= min_dist for j in pick):
            pick.append(int(i))
            if len(pick) == count:
                break
    return np.asarray(pick, np.int64)


def wavelength(model: TwoStage) -> float:
    """The carrier wavelength [m] of the model's dataset."""
    from ..rf.array import SPEED_OF_LIGHT

    return SPEED_OF_LIGHT / float(model.data.frequency_hz)


def _hop(query: Query, region: SearchRegion, xs: np.ndarray, ls: np.ndarray, *, spacing: float):
    """The best of a 5 x 5 grid of ``spacing`` [m] centred on each point of ``xs`` (float [S, 2],
    losses ``ls`` [S]): a coherent field's loss has a minimum every half wavelength or so along a
    path (its fringes), and a descent ends in the one nearest its start, so the points a quarter
    and a half wavelength away on either side are tried. Returns (float64 [S, 2], float64 [S])."""
    off = spacing * np.stack(np.meshgrid(np.arange(-2, 3), np.arange(-2, 3), indexing="ij"), -1).reshape(-1, 2)
    off = off[np.any(off != 0, axis=1)]
    cand = (np.asarray(xs, np.float64)[:, None, :] + off[None]).reshape(-1, 2)
    ok = region.free(cand)
    cl = np.full(len(cand), np.inf)
    if ok.any():
        cl[ok] = query.losses(cand[ok])
    cl = cl.reshape(len(xs), len(off))
    j = np.argmin(cl, axis=1)
    best = cl[np.arange(len(xs)), j]
    take = best < ls
    out = np.asarray(xs, np.float64).copy()
    out[take] = cand.reshape(len(xs), len(off), 2)[np.arange(len(xs)), j][take]
    return out, np.where(take, best, ls)


def _descend_ad(query: Query, region: SearchRegion, starts: np.ndarray, *, steps: int, lr_m: float):
    """Adam on (x, y) from every start at once; a step out of the region is not taken. Returns the
    best (point float64 [S, 2], loss float64 [S]) met by each start."""
    x = np.asarray(starts, np.float64).copy()
    m1, m2 = np.zeros_like(x), np.zeros_like(x)
    b1, b2, eps = 0.9, 0.999, 1e-12
    best_x, best_l = x.copy(), np.full(len(x), np.inf)
    for t in range(1, steps + 1):
        loss, g = query.loss_and_grad(x)
        better = loss < best_l
        best_x[better], best_l[better] = x[better], loss[better]
        if t == steps:
            break
        lr = lr_m * (0.1 ** ((t - 1) / max(steps - 1, 1)))
        m1 = b1 * m1 + (1 - b1) * g
        m2 = b2 * m2 + (1 - b2) * g * g
        step = lr * (m1 / (1 - b1 ** t)) / (np.sqrt(m2 / (1 - b2 ** t)) + eps)
        new = x - step
        ok = region.free(new)
        x[ok] = new[ok]
    return best_x, best_l


def _descend_nelder_mead(query: Query, region: SearchRegion, starts: np.ndarray, *, steps: int, simplex_m: float):
    """SciPy's bounded Nelder-Mead from every start (at most ``4 * steps`` losses each; a point out
    of the region costs 10). Returns the best (point float64 [S, 2], loss float64 [S])."""
    from scipy.optimize import minimize

    def f(v):
        return float(query.losses(v[None])[0]) if region.free(v[None])[0] else 10.0

    best_x, best_l = [], []
    for s in np.asarray(starts, np.float64):
        simplex = np.stack([s, s + [simplex_m, 0.0], s + [0.0, simplex_m]])
        r = minimize(f, s, method="Nelder-Mead", bounds=list(zip(region.lo, region.hi)),
                     options={"maxfev": 4 * steps, "xatol": 0.005, "fatol": 1e-6, "initial_simplex": simplex})
        best_x.append(r.x if r.fun <= f(s) else s)
        best_l.append(min(r.fun, f(s)))
    return np.asarray(best_x), np.asarray(best_l)


def refine(query: Query, region: SearchRegion, starts: np.ndarray, *, steps: int = 30, lr_m: float = 0.03,
           grid_m: float = 0.25, descent: str = "ad") -> tuple[np.ndarray, np.ndarray]:
    """Descend from each start, hop to the best neighbouring fringe, descend again (the search of
    :func:`locate` after its grid).

    Args:
        query: what is compared; region: where the feet may be; starts: float [S, 2] (x, y) [m];
        steps: descent steps (AD) or a quarter of the losses per start (Nelder-Mead); lr_m: first
        AD step [m]; grid_m: the grid spacing the starts came from [m] (Nelder-Mead's simplex);
        descent: "ad" or "nelder_mead".

    Returns:
        (float64 [S, 2] the best point met from each start, float64 [S] its loss).
    """
    hop = wavelength(query.model) / 4

    def descend(x0, n, scale):
        if descent == "ad":
            return _descend_ad(query, region, x0, steps=n, lr_m=scale)
        return _descend_nelder_mead(query, region, x0, steps=n, simplex_m=scale)

    xs, ls = descend(np.asarray(starts, np.float64).reshape(-1, 2), steps, lr_m if descent == "ad" else 0.5 * grid_m)
    hx, hl = _hop(query, region, xs, ls, spacing=hop)                  # the best neighbouring fringe
    px, pl = descend(hx, max(1, steps // 3), lr_m / 3 if descent == "ad" else hop / 2)
    return np.where((pl < hl)[:, None], px, hx), np.minimum(pl, hl)


def locate(model: TwoStage, pas: np.ndarray, positions: np.ndarray, *, grid_m: float = 0.25, starts: int = 4,
           steps: int = 30, lr_m: float = 0.03, loss: str = "train", downsample: int = 2, region: str = "walk",
           descent: str = "auto", search: SearchRegion | None = None, empty: np.ndarray | None = None,
           score_at: np.ndarray | None = None) -> dict:
    """Where the person stands, from PAS taken at ``positions`` (see the module docstring).

    Args:
        model: :func:`open_two_stage`'s model; pas: float [K, 90, 360] or [90, 360]; positions:
            float [K, 3] or [3] the moving device [m]; grid_m: coarse grid spacing [m]; starts:
            descent starts; steps: descent steps (AD) or a quarter of the losses per start
            (Nelder-Mead); lr_m: first AD step [m]; loss: "train" or "ssim"; downsample: block size;
            region: "walk" or "room" (:meth:`SearchRegion.of`); descent: "auto" (AD where
            the person field allows it, else Nelder-Mead), "ad", "nelder_mead" or "none" (the grid
            alone); search: a region made before (``region`` is then ignored); empty: None, or the
            empty room's PAS at ``positions`` (float [K, 90, 360]): the model's change is then
            fitted on top of them (:class:`Query`); score_at: None, or feet positions float [M, 2 or
            3] [m] whose losses are returned too (e.g. the true one).

    Returns:
        {"position": float64 [3] feet [m], "loss": float, "grid_position": float64 [3] the best
        grid point, "grid_loss": float, "descent": the kind used, "reference": "empty" or "none",
        "loss_without_person": the background alone's loss, "losses_at": float64 [M] (with
        ``score_at``), "losses_evaluated": int, "views": K}.
    """
    if descent not in ("auto", "ad", "nelder_mead", "none"):
        raise ConfigError(f"descent must be 'auto', 'ad', 'nelder_mead' or 'none', got {descent!r}")
    if starts < 1 or steps < 1:
        raise ConfigError(f"starts and steps must be >= 1, got {starts} and {steps}")
    if descent == "ad" and not model.differentiable:
        raise ConfigError(f"descent 'ad' needs a person field differentiable in the position; "
                          f"{type(model.person).__name__} is not (use 'nelder_mead')")
    kind = ("ad" if model.differentiable else "nelder_mead") if descent == "auto" else descent
    reg = search or SearchRegion.of(model, region=region)
    q = Query(model, pas, positions, loss=loss, downsample=downsample, empty=empty)
    grid = reg.grid(grid_m)
    gl = q.losses(grid)
    best = int(np.argmin(gl))
    pick = _spread_starts(grid, gl, starts, 2 * grid_m)
    if kind == "none":
        xs, ls = grid[pick], gl[pick]
    else:
        xs, ls = refine(q, reg, grid[pick], steps=steps, lr_m=lr_m, grid_m=grid_m, descent=kind)
    i = int(np.argmin(ls))
    x, lo = (xs[i], float(ls[i])) if ls[i] <= gl[best] else (grid[best], float(gl[best]))
    out = {"position": reg.feet(x)[0], "loss": lo, "grid_position": reg.feet(grid[best])[0],
           "grid_loss": float(gl[best]), "descent": kind, "reference": q.reference,
           "loss_without_person": q.loss_without_person(), "losses_evaluated": int(q.evaluations), "views": q.k}
    if score_at is not None:
        out["losses_at"] = q.losses(np.asarray(score_at, np.float64).reshape(len(score_at), -1)[:, :2])
    return out


# ------------------------------------------------------------------------ floors
def fingerprint(data: SampleData, query_pas: np.ndarray, antennas: np.ndarray, *, states: np.ndarray) -> dict:
    """The fingerprint floor: of the dataset states ``states`` (int [S], person states), the one
    whose measured PAS at ``antennas`` (int [K] antenna indices) are most like ``query_pas``
    (float [K, 90, 360], normalised): highest mean SSIM over the K PAS (Dr.Jit float32 SSIM,
    skimage's definition). Returns {"state": int, "position": float64 [3], "ssim": float}."""
    import drjit as dr

    from ..core import backend as B
    from ..train import loss as L

    states = np.asarray(states, np.int64)
    antennas = np.asarray(antennas, np.int64)
    k = len(antennas)
    qn = minmax(np.asarray(query_pas, np.float32))
    per = max(1, VIEWS_PER_CALL // k)
    score = np.empty(len(states))
    lookup = {(int(s), int(a)): i for i, (s, a) in enumerate(zip(data.states, data.antennas))}
    for i in range(0, len(states), per):
        part = states[i:i + per]
        rows = np.array([lookup[(int(s), int(a))] for s in part for a in antennas], np.int64)
        ref = data.pas(rows)
        with dr.suspend_grad():
            s = L.ssim(B.TensorXf(ref), B.TensorXf(np.tile(qn, (len(part), 1, 1))))
            sc = dr.block_sum(s, k) * (1.0 / k)
        score[i:i + len(part)] = np.asarray(sc.numpy(), np.float64).reshape(len(part))
    j = int(np.argmax(score))
    row = lookup[(int(states[j]), int(antennas[0]))]
    return {"state": int(states[j]), "position": np.asarray(data.person_pos[row], np.float64), "ssim": float(score[j])}


# ------------------------------------------------------------------------ where it fails
def failure_proxies(feet: np.ndarray, array_pos: np.ndarray, transmitters: np.ndarray, geometry=None) -> dict:
    """Geometric proxies of why a person position is hard to find.

    Args:
        feet: float [3] the true feet position [m]; array_pos: float [K, 3] the array centres of
        the query's views [m]; transmitters: float [K, 3] their transmitters [m]; geometry: the
        room (:class:`~rfmitsuba.sim.geometry.RoomGeometry`) or None.

    Returns:
        {"distance_to_array_m": horizontal distance to the nearest array centre, "distance_to_tx_m":
        to the nearest transmitter, "blocked_share": share of the views whose direct path
        (transmitter -> array centre) passes within :data:`BODY_RADIUS_M` of the body axis at a
        height within the body, "hidden_from_tx": furniture lies on the line from the transmitter
        to the chest (:data:`CHEST_M` above the feet; None without a room), "hidden_share": share
        of the array centres from which furniture hides the chest (None without a room)}.
    """
    h = np.asarray(feet, np.float64).reshape(3)
    x = np.asarray(array_pos, np.float64).reshape(-1, 3)
    y = np.asarray(transmitters, np.float64).reshape(-1, 3)
    d = x - y
    w = h[None, :2] - y[:, :2]
    t = np.clip((w * d[:, :2]).sum(1) / np.maximum((d[:, :2] ** 2).sum(1), 1e-12), 0.0, 1.0)
    r = np.hypot(*(w - t[:, None] * d[:, :2]).T)
    z = y[:, 2] + t * d[:, 2]
    blocked = (r < BODY_RADIUS_M) & (z >= h[2]) & (z <= h[2] + BODY_HEIGHT_M)
    out = {"distance_to_array_m": float(np.hypot(*(x[:, :2] - h[:2]).T).min()),
           "distance_to_tx_m": float(np.hypot(*(y[:, :2] - h[:2]).T).min()),
           "blocked_share": float(blocked.mean()), "hidden_from_tx": None, "hidden_share": None}
    if geometry is not None:
        chest = h + [0.0, 0.0, CHEST_M]

        def hidden(a):
            who = geometry.segment_blocker(a, chest)
            return who is not None and who != "the walls"

        out["hidden_from_tx"] = bool(hidden(y[0]))
        out["hidden_share"] = float(np.mean([hidden(a) for a in np.unique(x, axis=0)]))
    return out


# ------------------------------------------------------------------------ evaluation on the held-out walk
def _stats_cm(err_m: np.ndarray) -> dict:
    e = 100.0 * np.asarray(err_m, np.float64)
    return {"median_cm": float(np.median(e)), "p90_cm": float(np.percentile(e, 90)), "mean_cm": float(e.mean()),
            "n": int(len(e))}


def query_antennas(data: SampleData, *, antennas: str = "all", views: int = 0, seed: int = 0) -> np.ndarray:
    """The antenna indices of every evaluation query: the dataset's test antennas ("test") or all
    ("all"); ``views`` > 0 keeps that many of them (seeded, sorted). int64 [K]."""
    if antennas not in ("test", "all"):
        raise ConfigError(f"antennas must be 'test' or 'all', got {antennas!r}")
    a = (np.asarray(data.split.antenna_test, np.int64) if antennas == "test"
         else np.unique(np.asarray(data.antennas, np.int64)))
    if views < 0:
        raise ConfigError(f"views must be >= 0 (0 = all), got {views}")
    if views and views < len(a):
        a = np.sort(np.random.default_rng([seed, 11]).choice(a, views, replace=False))
    if len(a) == 0:
        raise DatasetError(f"{data.path}: no {antennas} antenna positions to take the queries at")
    return a


def evaluate_locate(run: str | Path, *, antennas: str = "all", views: int = 0, reference: str = "empty",
                    grid_m: float = 0.25, starts: int = 4, steps: int = 30, lr_m: float = 0.03, loss: str = "train",
                    downsample: int = 2, region: str = "walk", descent: str = "auto", quiet: bool = False) -> dict:
    """Locate every held-out walk position (the dataset's person test split) with every Ours job
    of ``run`` (:func:`job_folders`), beside the fingerprint and centre floors.

    Each query is one held-out person state seen at the antennas of :func:`query_antennas`
    (``antennas``, ``views``): the dataset's measured PAS there, the person's true feet position the
    answer. ``reference``: "empty" gives :func:`locate` the dataset's empty-room PAS at the same
    antennas (the model's change is fitted on top of them), "none" compares the model's PAS
    with the query as they are. The other options are :func:`locate`'s.

    Returns:
        a JSON-ready dict: "dataset", "jobs" (labels), "antennas" (indices), "states", "truth"
        [Q][3], "estimates" {"model": {label: [Q][3]}, "fingerprint": [Q][3], "walk_centroid": [3],
        "room_centre": [3] or None}, "errors_cm" (the same keys, [Q] per job and floor), "stats"
        {"model" (pooled over jobs), "model_per_job" {label: stats}, "fingerprint",
        "walk_centroid", "room_centre": {"median_cm", "p90_cm", "mean_cm", "n"}}, "proxies" [Q]
        (:func:`failure_proxies`), "settings", "descent", "time_s", "losses_evaluated".

    Raises:
        RunError: no two-stage job, or jobs trained on different datasets.
    """
    from ..core import progress

    if reference not in REFERENCES:
        raise ConfigError(f"reference must be one of {REFERENCES}, got {reference!r}")
    t0 = time.perf_counter()
    jobs = job_folders(run)
    models = []
    for label, jd in jobs:
        models.append((label, open_two_stage(jd)))
    paths = {str(Path(m.data.path).resolve()) for _, m in models}
    if len(paths) > 1:
        raise RunError(f"{run}: its jobs trained on different datasets ({', '.join(sorted(paths))})")
    data = models[0][1].data
    sp = data.split
    test_states = np.asarray(sp.person_test, np.int64) + 1
    train_states = np.asarray(sp.person_train, np.int64) + 1
    if len(test_states) == 0:
        raise DatasetError(f"{data.path}: no held-out walk positions (person test split) to locate")
    ant = query_antennas(data, antennas=antennas, views=views)
    lookup = {(int(s), int(a)): i for i, (s, a) in enumerate(zip(data.states, data.antennas))}
    search = {label: SearchRegion.of(m, region=region) for label, m in models}
    geometry = next(iter(search.values())).geometry
    truth, fp, proxies = [], [], []
    est = {label: [] for label, _ in models}
    diag = {label: [] for label, _ in models}
    used, evals = set(), 0
    with progress.bar(len(test_states) * (len(models) + 1), desc="locate", unit="query", quiet=quiet) as pb:
        for s in test_states:
            rows = np.array([lookup[(int(s), int(a))] for a in ant], np.int64)
            pas = data.pas(rows)
            empty = data.pas(np.array([lookup[(0, int(a))] for a in ant], np.int64)) if reference == "empty" else None
            feet = np.asarray(data.person_pos[rows[0]], np.float64)
            truth.append(feet)
            fp.append(fingerprint(data, pas, ant, states=train_states)["position"])
            x, y, q = data.positions(rows)
            proxies.append(failure_proxies(feet, x, y, geometry))
            pb.update(1)
            for label, m in models:
                r = locate(m, pas, q, grid_m=grid_m, starts=starts, steps=steps, lr_m=lr_m, loss=loss,
                           downsample=downsample, descent=descent, search=search[label], empty=empty,
                           score_at=feet[None])
                est[label].append(r["position"])
                diag[label].append({"estimate": r["loss"], "truth": float(r["losses_at"][0]),
                                    "no_person": r["loss_without_person"]})
                used.add(r["descent"])
                evals += r["losses_evaluated"]
                pb.update(1)
    truth = np.asarray(truth)
    x0, y0, _ = data.positions(np.array([lookup[(int(test_states[0]), int(a))] for a in ant], np.int64))
    centroid = np.concatenate([models[0][1].walk[:, :2].mean(0), [models[0][1].feet_z]])
    room_centre = None
    if geometry is not None:
        lo, hi = geometry.bounds
        room_centre = np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), models[0][1].feet_z])

    def err(p):
        return np.hypot(*(np.asarray(p, np.float64).reshape(-1, 3)[:, :2] - truth[:, :2]).T)

    errors = {"model": {label: err(e) for label, e in est.items()}, "fingerprint": err(fp),
              "walk_centroid": err(np.tile(centroid, (len(truth), 1)))}
    if room_centre is not None:
        errors["room_centre"] = err(np.tile(room_centre, (len(truth), 1)))
    stats = {"model": _stats_cm(np.concatenate(list(errors["model"].values()))),
             "model_per_job": {label: _stats_cm(e) for label, e in errors["model"].items()},
             "fingerprint": _stats_cm(errors["fingerprint"]), "walk_centroid": _stats_cm(errors["walk_centroid"]),
             "room_centre": _stats_cm(errors["room_centre"]) if room_centre is not None else None}
    return {
        "run": str(run), "dataset": str(data.path), "task": data.task,
        "scene_xml": None if data.scene_xml is None else str(data.scene_xml), "jobs": [label for label, _ in models],
        "job_folders": [str(jd) for _, jd in jobs], "antennas": ant.tolist(), "states": test_states.tolist(),
        "truth": truth.tolist(),
        "estimates": {"model": {k: np.asarray(v).tolist() for k, v in est.items()},
                      "fingerprint": np.asarray(fp).tolist(), "walk_centroid": centroid.tolist(),
                      "room_centre": None if room_centre is None else room_centre.tolist()},
        "errors_cm": {"model": {k: (100 * v).tolist() for k, v in errors["model"].items()},
                      **{k: (100 * v).tolist() for k, v in errors.items() if k != "model"}},
        "stats": stats, "proxies": proxies, "losses": diag,
        "walk": models[0][1].walk.tolist(), "region": next(iter(search.values())).kind,
        "array_positions": np.unique(x0, axis=0).tolist(), "transmitters": np.unique(y0, axis=0).tolist(),
        "settings": {"antennas": antennas, "views": int(len(ant)),
                     "available_views": int(len(query_antennas(data, antennas=antennas))), "reference": reference, "grid_m": grid_m, "starts": starts,
                     "steps": steps, "lr_m": lr_m, "loss": loss, "downsample": downsample, "region": region,
                     "descent": descent},
        "descent": sorted(used), "losses_evaluated": int(evals), "time_s": time.perf_counter() - t0,
    }


# ------------------------------------------------------------------------ figure and report
def plot_locate(path: str | Path, result: dict) -> Path:
    """PNG: left, the room's top view with the walk, every true held-out position and its estimates
    (model per job, fingerprint) joined to it; right, the error against the distance from the
    fixed device (the transmitter of a moving-RX dataset, the array of a moving-TX one), model
    and fingerprint, blocked direct paths marked."""
    from ..core import plots

    truth = np.asarray(result["truth"], np.float64)
    fig, (ax, bx) = plots.subplots(1, 2, figsize=(13, 6.4))
    geom = None
    if result.get("scene_xml") and Path(result["scene_xml"]).is_file():
        from ..sim.geometry import RoomGeometry

        geom = RoomGeometry.from_xml(result["scene_xml"])
        geom.plot_top_view(ax, labels=True)
    walk = np.asarray(result["walk"], np.float64)
    ax.plot(walk[:, 0], walk[:, 1], ".", color="0.6", ms=4, label="training walk")
    arr, tx = np.asarray(result["array_positions"]), np.asarray(result["transmitters"])
    ax.plot(arr[:, 0], arr[:, 1], "s", color="0.3", ms=2.5, label="array positions of the queries")
    ax.plot(tx[:, 0], tx[:, 1], "*", color="red", ms=12, ls="none", label="transmitter" if len(tx) == 1 else
            "transmitters")
    colours = ["#1f77b4", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf"]
    for i, (label, e) in enumerate(result["estimates"]["model"].items()):
        e = np.asarray(e, np.float64)
        c = colours[i % len(colours)]
        for a, b in zip(truth, e):
            ax.plot([a[0], b[0]], [a[1], b[1]], "-", color=c, lw=0.7, alpha=0.7)
        ax.plot(e[:, 0], e[:, 1], "o", color=c, ms=5, label=f"model ({label})")
    f = np.asarray(result["estimates"]["fingerprint"], np.float64)
    ax.plot(f[:, 0], f[:, 1], "^", mfc="none", mec="#d62728", ms=7, label="fingerprint")
    ax.plot(truth[:, 0], truth[:, 1], "kx", ms=8, mew=2, label="true position")
    cen = result["estimates"]["walk_centroid"]
    ax.plot(cen[0], cen[1], "P", color="#ff7f0e", ms=10, label="walk centroid")
    if geom is None:
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    handles, labels = ax.get_legend_handles_labels()
    ax.set_title(f"true and estimated positions ({len(truth)} held-out, {result['settings']['views']} PAS each)",
                 fontsize=9)
    fixed = "distance_to_tx_m" if result["task"] == "rx" else "distance_to_array_m"
    dist = np.array([p[fixed] for p in result["proxies"]])
    blocked = np.array([p["blocked_share"] for p in result["proxies"]]) > 0
    for i, (label, e) in enumerate(result["errors_cm"]["model"].items()):
        e = np.asarray(e)
        c = colours[i % len(colours)]
        bx.plot(dist[~blocked], e[~blocked], "o", color=c, ms=5, label=f"model ({label})")
        bx.plot(dist[blocked], e[blocked], "o", mfc="none", mec=c, ms=7)
    fe = np.asarray(result["errors_cm"]["fingerprint"])
    bx.plot(dist, fe, "^", mfc="none", mec="#d62728", ms=7, label="fingerprint")
    bx.axhline(result["stats"]["walk_centroid"]["median_cm"], color="#ff7f0e", ls="--", lw=1,
               label="walk centroid (median)")
    plots.label(bx, xlabel=f"distance from the {'transmitter' if result['task'] == 'rx' else 'array'} (m)",
                ylabel="error (cm)")
    bx.set_title("error against distance (hollow circles: the person blocks a direct path)", fontsize=9)
    fig.legend(handles, labels, loc="lower left", bbox_to_anchor=(0.03, 0.0), ncol=4, fontsize=7)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    return plots.save(fig, path, tight=False)


def _row(name: str, s: dict | None) -> str:
    if not s:
        return f"| {name} | n/a | n/a | n/a | 0 |"
    return f"| {name} | {s['median_cm']:.0f} | {s['p90_cm']:.0f} | {s['mean_cm']:.0f} | {s['n']} |"


def _split_rows(result: dict, values: np.ndarray, edges: list, names: list[str], what: str) -> list[str]:
    """Median error [cm] of the model (pooled) and the fingerprint per group of a proxy."""
    model = np.asarray(list(result["errors_cm"]["model"].values()), np.float64)   # [J, Q]
    fp = np.asarray(result["errors_cm"]["fingerprint"], np.float64)
    out = []
    for name, lo, hi in zip(names, edges[:-1], edges[1:]):
        sel = (values >= lo) & (values < hi)
        if not sel.any():
            continue
        out.append(f"| {what} {name} | {int(sel.sum())} | {np.median(model[:, sel]):.0f} | "
                   f"{np.percentile(model[:, sel], 90):.0f} | {np.median(fp[sel]):.0f} |")
    return out


def _why_lines(result: dict) -> list[str]:
    """Markdown: of the queries with an error over :data:`MISS_CM`, how many the search missed (the
    model's loss at the true position is below its estimate's) and how many the model missed (it
    is not), and how often the model's person at the true position explains the query worse than
    no person at all."""
    d = result.get("losses")
    if not d:
        return []
    rows = [(e, r) for label in d for e, r in zip(result["errors_cm"]["model"][label], d[label])]
    miss = [r for e, r in rows if e > MISS_CM]
    search = sum(r["truth"] < r["estimate"] for r in miss)
    worse = sum(r["truth"] > r["no_person"] for _, r in rows)
    return ["", f"Of the {len(rows)} estimates, {len(miss)} are more than {MISS_CM:g} cm off: for {search} of them "
            f"the model's loss at the true position is lower than at its estimate (the search missed it), for "
            f"{len(miss) - search} it is not (the model prefers another place). For {worse} of the {len(rows)} the "
            "model's person at the true position explains the query worse than the background alone (no person): "
            "there the model has not learned what the person does to these PAS."]


def report_markdown(result: dict, *, command: str | None = None) -> str:
    """The Markdown report of :func:`evaluate_locate`'s result."""
    s, st = result["settings"], result["stats"]
    lines = [f"# Localisation with `{result['run']}`", "",
             f"Dataset `{result['dataset']}` (moving {result['task'].upper()}); {len(result['states'])} held-out walk "
             f"positions (the dataset's person test split), each located from {s['views']} PAS at "
             f"{'its test' if s['antennas'] == 'test' else 'its'} antenna positions"
             f"{' (a seeded subset)' if s['views'] < s.get('available_views', s['views']) else ''}; jobs "
             f"{', '.join(result['jobs'])}; "
             + ("the model's change fitted on top of the empty room's measured PAS at the same antennas. "
                if s.get("reference") == "empty" else "the model's PAS compared with the query as it is. ")
             + f"Search: {result['region']} region, {s['grid_m']} m grid, {s['starts']} starts, "
             f"{', '.join(result['descent'])} descent ({s['steps']} steps), loss "
             f"{'0.8 L1 + 0.2 (1 - SSIM)' if s['loss'] == 'train' else '1 - SSIM'} at "
             f"{90 // s['downsample']} x {360 // s['downsample']}. Errors are horizontal distances in cm.", "",
             "| estimate | median (cm) | 90th pct (cm) | mean (cm) | n |", "|---|---|---|---|---|",
             _row("model (all jobs)", st["model"])]
    if len(st["model_per_job"]) > 1:
        lines += [_row(f"model ({k})", v) for k, v in st["model_per_job"].items()]
    lines += [_row("fingerprint (nearest training walk state by SSIM)", st["fingerprint"]),
              _row("walk centroid", st["walk_centroid"])]
    if st.get("room_centre"):
        lines.append(_row("room centre", st["room_centre"]))
    px = result["proxies"]
    dist = np.array([p["distance_to_array_m"] for p in px])
    dtx = np.array([p["distance_to_tx_m"] for p in px])
    lines += ["", "## Where it fails", "",
              "Median and 90th-percentile error (cm) of the model (pooled over jobs) and the fingerprint's median, "
              "per group of held-out positions.", "",
              "| group | positions | model median | model p90 | fingerprint median |", "|---|---|---|---|---|"]
    q = np.quantile(dist, [0, 1 / 3, 2 / 3, 1])
    q[-1] += 1e-9
    lines += _split_rows(result, dist, list(q), [f"{a:.2f}-{b:.2f} m" for a, b in zip(q[:-1], q[1:])],
                         "distance from the nearest array position")
    q = np.quantile(dtx, [0, 1 / 3, 2 / 3, 1])
    q[-1] += 1e-9
    lines += _split_rows(result, dtx, list(q), [f"{a:.2f}-{b:.2f} m" for a, b in zip(q[:-1], q[1:])],
                         "distance from the transmitter" if result["task"] == "rx" else "distance from the nearest TX")
    blocked = np.array([p["blocked_share"] for p in px])
    lines += _split_rows(result, (blocked > 0).astype(float), [0, 0.5, 1.5],
                         ["no", "yes"], "blocks a direct path:")
    if px and px[0]["hidden_from_tx"] is not None:
        hid = np.array([float(p["hidden_from_tx"]) for p in px])
        lines += _split_rows(result, hid, [0, 0.5, 1.5], ["no", "yes"], "furniture between TX and chest:")
        hs = np.array([p["hidden_share"] for p in px])
        lines += _split_rows(result, (hs > 0).astype(float), [0, 0.5, 1.5], ["none", "some"],
                             "array positions that see the chest through furniture:")
    lines += _why_lines(result)
    lines += ["", f"{result['losses_evaluated']} model losses evaluated in {result['time_s']:.0f} s.", ""]
    if command:
        lines += ["Regenerate with:", "", "```", command, "```", ""]
    return "\n".join(lines)
