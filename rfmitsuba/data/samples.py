"""Flat (state, antenna) views of a dataset: what Stage 2 and the baselines train on.

A :class:`SampleData` looks like :class:`rfmitsuba.train.trainer.TrainData` to the
:class:`~rfmitsuba.train.trainer.Trainer` (``antenna_pos``, ``view_pos``, ``train``, ``test``,
``pas(idx, d=)``...), but its index ``k`` runs over *samples*: pairs of a dataset state
(0 = empty room, s > 0 = person at ``person_positions[s-1]``) and an antenna position.

* which states: ``"empty"`` (state 0), ``"person"`` (states 1..H) or ``"all"``;
* ``duplicate``: the sample list repeated (the Baseline-duplicated ablation);
* ``noise_snr_db``: complex white noise added to the *training* channels at this SNR
  (relative to the mean channel power per sample) and the PAS recomputed with the
  Bartlett beamformer; datasets without channels get the noise on the PAS amplitude.

Training samples: antenna in the antenna-train split and (state 0 or person in the
person-train split). Test samples: antenna-test x (state 0 for "empty", person-test states
otherwise). Nothing of a test antenna or a test person position is ever a training sample.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.encoding import sin_encoding
from ..core.errors import ConfigError, DatasetError
from ..core.legacy_names import current_name
from ..rf import bartlett_ref as _pas
from ..rf.grid import PAS_SHAPE
from .layout import grid_layout
from .pas_cache import state_images
from .store import Dataset, open_dataset
from .views import PasRows, TrainData, normalised_pas

STATE_SETS = ("empty", "person", "all")
#: how a subset of training antenna positions is drawn (``SampleData.open_samples(layout=...)``)
LAYOUTS = ("random", "grid")


def feature_box(lo: np.ndarray, hi: np.ndarray, person_pos: np.ndarray) -> np.ndarray:
    """The box that normalises person positions: ``lo``..``hi`` (float [3] each, the scene's
    bounds) widened to hold every finite feet position of ``person_pos`` (float [K, 3]) and a body
    of 1.8 m above it, grown by 0.3 m on every side [m]: float64 [2, 3]."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    p = np.asarray(person_pos, np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(1)]
    if len(p):
        lo, hi = np.minimum(lo, p.min(0)), np.maximum(hi, p.max(0) + [0.0, 0.0, 1.8])
    return np.stack([lo - 0.3, hi + 0.3])


def person_features(person_pos: np.ndarray, box: np.ndarray, *, octaves: int = 3) -> np.ndarray:
    """Network input describing a person position (or its absence).

    Args:
        person_pos: float [K, 3] metres; NaN rows = empty room.
        box: float [2, 3] metres, the normalisation box (lo, hi).
        octaves: sine/cosine octaves of the encoding.

    Returns:
        float32 [K, 3 * (1 + 2 * octaves) + 1]: position mapped to [0, 0.5] per axis, its
        sin/cos encoding (period 1), and a presence flag (1 = a person is there); all zeros
        for an empty room.
    """
    h = np.asarray(person_pos, np.float64).reshape(-1, 3)
    box = np.asarray(box, np.float64).reshape(2, 3)
    present = np.isfinite(h).all(axis=1)
    x01 = np.where(present[:, None], (h - box[0]) / (box[1] - box[0]), 0.0)
    out = np.concatenate([sin_encoding(x01, octaves), present[:, None].astype(np.float64)], axis=1)
    out[~present] = 0.0
    return out.astype(np.float32)


def num_person_features(octaves: int = 3) -> int:
    """Width of :func:`person_features`."""
    return 3 * (1 + 2 * octaves) + 1


def add_noise_channels(channel: np.ndarray, snr_db: float, *, rng: np.random.Generator) -> np.ndarray:
    """Complex white Gaussian noise at ``snr_db`` relative to each row's mean power.

    Args:
        channel: complex [K, M]; snr_db: signal-to-noise ratio in dB; rng: generator.

    Returns:
        complex64 [K, M].
    """
    h = np.asarray(channel, np.complex128)
    p = np.mean(np.abs(h) ** 2, axis=1, keepdims=True)
    sigma = np.sqrt(p / 10 ** (snr_db / 10) / 2)
    n = sigma * (rng.standard_normal(h.shape) + 1j * rng.standard_normal(h.shape))
    return (h + n).astype(np.complex64)


def add_noise_pas(pas: np.ndarray, snr_db: float, *, rng: np.random.Generator) -> np.ndarray:
    """White Gaussian noise on PAS amplitude images at ``snr_db`` relative to each image's mean
    power; float [K, H, W] -> float32 [K, H, W] (clipped at 0)."""
    x = np.asarray(pas, np.float64)
    p = np.mean(x ** 2, axis=(1, 2), keepdims=True)
    sigma = np.sqrt(p / 10 ** (snr_db / 10))
    return np.maximum(x + sigma * rng.standard_normal(x.shape), 0).astype(np.float32)


@dataclass
class SampleData(TrainData):
    """Samples over (state, antenna) pairs; see the module docstring.

    Extra attributes: ``states`` int64 [K] dataset state per sample, ``antennas`` int64 [K]
    antenna index per sample, ``person_pos`` float64 [K, 3] metres (NaN = empty room),
    ``people_pos`` float64 [K, P, 3] metres (every person; ``[:, 0]`` is ``person_pos``),
    ``box`` float64 [2, 3] metres (bounds used to normalise person positions).
    """

    states: np.ndarray = None
    antennas: np.ndarray = None
    person_pos: np.ndarray = None
    people_pos: np.ndarray = None
    noise_snr_db: float | None = None
    noise_seed: int = 0
    _ds: object = None
    _noisy: dict = None

    @classmethod
    def open_samples(cls, path: str | Path, *, states: str = "all", duplicate: int = 1,
                     noise_snr_db: float | None = None, noise_seed: int = 0,
                     train_antennas: int = 0, subset_seed: int = 0, layout: str = "random",
                     walk_frames: int | None = None) -> "SampleData":
        """Open a dataset folder as samples.

        Args:
            path: dataset folder (:mod:`rfmitsuba.data.store` format).
            states: "empty", "person" or "all".
            duplicate: how many times the sample list is repeated (>= 1).
            noise_snr_db: SNR of the noise added to training samples (None = no noise).
            noise_seed: seed of that noise.
            train_antennas: keep only this many training antenna positions (0 = all), shared by
                every state, laid out by ``layout``; the test split is unchanged.
            subset_seed: the seed of a "random" layout.
            layout: "random" (a seeded subset) or "grid" (a coarse grid over the free floor,
                :func:`rfmitsuba.data.layout.grid_layout`; no seed).
            walk_frames: train on the person only in the first this many walk positions (dataset
                states 1..walk_frames, in walk order; those in the test split stay test
                positions); None = the whole walk, 0 = none of it.

        Raises:
            ConfigError: bad ``states`` / ``duplicate``; DatasetError: no person states when
            they are asked for.
        """
        states = current_name(states)
        if states not in STATE_SETS:
            raise ConfigError(f"states must be one of {STATE_SETS}, got {states!r}")
        if duplicate < 1:
            raise ConfigError(f"duplicate must be >= 1, got {duplicate}")
        if layout not in LAYOUTS:
            raise ConfigError(f"layout must be one of {LAYOUTS}, got {layout!r}")
        if walk_frames is not None and walk_frames < 0:
            raise ConfigError(f"walk_frames must be >= 0 or None, got {walk_frames}")
        base = TrainData.open(path, state=0)

        ds = open_dataset(path)
        A, S = ds.num_antennas, ds.num_states
        if states != "empty" and S < 2:
            raise DatasetError(f"{path}: has no person-present states (needed for states={states!r})")
        st = {"empty": [0], "person": list(range(1, S)), "all": list(range(S))}[states]
        sp = ds.split
        h_train = set(int(h) + 1 for h in sp.person_train if walk_frames is None or h < walk_frames)
        h_test = set(int(h) + 1 for h in sp.person_test)
        s_arr = np.repeat(np.asarray(st, np.int64), A)
        a_arr = np.tile(np.arange(A, dtype=np.int64), len(st))
        ant_train = np.asarray(base.train)
        if train_antennas and train_antennas < len(ant_train) and layout == "grid":
            ant_train = np.sort(ant_train[grid_layout(base.antenna_pos[ant_train], train_antennas)])
        elif train_antennas and train_antennas < len(ant_train):
            ant_train = np.sort(np.random.default_rng([subset_seed, 7]).choice(ant_train, train_antennas, replace=False))
        a_train = np.isin(a_arr, ant_train)
        a_test = np.isin(a_arr, base.test)
        s_train = np.array([s == 0 or s in h_train for s in s_arr])
        s_test = np.array([(s == 0 and states == "empty") or s in h_test for s in s_arr])
        train = np.flatnonzero(a_train & s_train)
        test = np.flatnonzero(a_test & s_test)
        if duplicate > 1:
            k = len(s_arr)
            s_arr, a_arr = np.tile(s_arr, duplicate), np.tile(a_arr, duplicate)
            train = np.concatenate([train + j * k for j in range(duplicate)])
        if len(train) == 0 or len(test) == 0:
            raise DatasetError(f"{path}: {len(train)} training and {len(test)} test samples for states={states!r}")
        hp = np.asarray(ds.person_pos, np.float64)[s_arr]
        ap = base.antenna_pos[a_arr]
        vp = base.view_pos[a_arr]
        lo, hi = base.bounds
        meshes = None
        try:
            meshes = base.meshes()
        except Exception:  # noqa: BLE001 - a scene that cannot be read only widens nothing
            meshes = None
        if meshes:
            allv = np.concatenate([v for v, _ in meshes])
            lo, hi = np.minimum(lo, allv.min(0)), np.maximum(hi, allv.max(0))
        box = feature_box(lo, hi, hp)
        data = cls(path=base.path, task=base.task, antenna_pos=ap, view_pos=vp, rx_to_world=base.rx_to_world,
                   train=np.sort(train), test=np.sort(test), scene_xml=base.scene_xml, transmitter=base.transmitter,
                   bounds=base.bounds, state=0, frequency_hz=base.frequency_hz, states=s_arr, antennas=a_arr,
                   person_pos=hp, people_pos=np.asarray(getattr(ds, "people_pos", ds.person_pos[:, None]),
                                                        np.float64)[s_arr],
                   noise_snr_db=noise_snr_db, noise_seed=int(noise_seed))
        data._ds = ds
        data._noisy = {}
        data.box = box
        data.split = sp
        return data

    def raw(self, idx: np.ndarray) -> np.ndarray:
        """Raw PAS of samples ``idx`` (noise added to training samples when configured):
        float32 [K, 90, 360]."""
        idx = np.asarray(idx, np.int64)
        out = np.zeros((len(idx), *PAS_SHAPE), np.float32)
        st = self.states[idx]
        an = self.antennas[idx]
        rows = (np.flatnonzero(np.isin(idx, self.train)) if self.noise_snr_db is not None
                else np.empty(0, np.int64))   # noisy training samples: made from the channels, not read
        clean = np.ones(len(idx), bool)
        clean[rows] = False
        for s in np.unique(st[clean]):
            sel = np.flatnonzero(clean & (st == s))
            order = np.argsort(an[sel])
            out[sel[order]] = np.asarray(self._ds.pas(int(s))[an[sel][order]], dtype=np.float32)
        if self.noise_snr_db is not None:
            for s in np.unique(st[rows]):
                sel = rows[st[rows] == s]
                self._make_noisy(int(s), an[sel])
                for j in sel:
                    out[j] = self._noisy[(int(s), int(an[j]))]
        return out

    def _make_noisy(self, state: int, antennas: np.ndarray) -> None:
        """Compute and cache the noisy training PAS of ``antennas`` (int [K]) of one state, those not
        cached yet, in one beamformer product (one PAS at a time cost 45 ms, mostly the steering
        matrix; 600 at once 0.4 ms each). The noise of each (state, antenna) comes from its own
        seeded generator, so it does not depend on which samples are asked for together."""
        todo = sorted({int(a) for a in antennas if (state, int(a)) not in self._noisy})
        if not todo:
            return
        snr = float(self.noise_snr_db)
        rngs = [np.random.default_rng([self.noise_seed, state, a]) for a in todo]
        try:
            ch = np.asarray(self._ds.channel(state)[todo])
        except DatasetError:
            ch = None
        if ch is not None and np.abs(ch).sum() > 0:
            noisy = np.concatenate([add_noise_channels(ch[i:i + 1], snr, rng=r) for i, r in enumerate(rngs)])
            imgs = _pas.bartlett(noisy, frequency_hz=float(self._ds.frequency_hz))
        else:
            pas = np.asarray(self._ds.pas(state)[todo])
            imgs = np.concatenate([add_noise_pas(pas[i:i + 1], snr, rng=r) for i, r in enumerate(rngs)])
        for a, img in zip(todo, imgs):
            self._noisy[(state, a)] = np.asarray(img, np.float32)

    def pas(self, idx: np.ndarray, *, d: int = 1) -> np.ndarray:
        """Min-max normalised PAS of samples ``idx``: float32 [K, 90/d, 360/d]
        (:func:`rfmitsuba.data.views.normalised_pas`). Block means (``d > 1``) of a dataset folder
        (not a NeRF2 folder) without noise are read from its cache of training images (:mod:`rfmitsuba.data.pas_cache`, made
        per state on first use), bit-identical to computing them.

        Raises:
            DatasetError: a PAS with NaN/inf values (naming state and antenna).
        """
        def bad(k):
            return (f"{self.path}: PAS of antenna position {int(self.antennas[k])} (state {int(self.states[k])}) "
                    "contains NaN or infinite values")

        if d == 1 or self.noise_snr_db is not None or not isinstance(self._ds, Dataset):   # a NeRF2 folder: no chunks
            return normalised_pas(idx, self.raw, d=d, bad=bad)
        idx = np.asarray(idx, np.int64)
        out = np.empty((len(idx), PAS_SHAPE[0] // d, PAS_SHAPE[1] // d), np.float32)
        st, an = self.states[idx], self.antennas[idx]
        ok = np.ones(len(idx), bool)
        for s in np.unique(st):
            sel = np.flatnonzero(st == s)
            images, finite = state_images(self._ds, int(s), d=d)
            order = np.argsort(an[sel], kind="stable")   # rows in file order: one pass over the memmap
            out[sel[order]] = images[an[sel][order]]
            ok[sel] = finite[an[sel]]
        if not ok.all():
            raise DatasetError(bad(int(idx[int(np.flatnonzero(~ok)[0])])))
        return out

    def pas_rows(self, idx: np.ndarray) -> PasRows:
        """The PAS of :meth:`pas` for samples ``idx`` (int [M]), read only when indexed
        (:class:`rfmitsuba.data.views.PasRows`)."""
        return PasRows(rows=np.asarray(idx, np.int64), read=self.pas)

    def features(self, idx: np.ndarray, *, octaves: int = 3, raw: bool = False, people: int = 1) -> np.ndarray:
        """:func:`person_features` of samples ``idx``: float32 [K, num_person_features(octaves)];
        with ``raw`` followed by the person position in metres (zeros for the empty room), [K, F + 3],
        and with ``people`` P > 1 by every person's, [K, F + 3 P] (DatasetError where the dataset
        walks fewer people)."""
        idx = np.asarray(idx, np.int64)
        hp = self.person_pos[idx]
        f = person_features(hp, self.box, octaves=octaves)
        if raw:
            if people > 1:
                pp = self.people_pos if self.people_pos is not None else self.person_pos[:, None]
                if pp.shape[1] < people:
                    raise DatasetError(f"{self.path}: {people} people asked for, the dataset walks {pp.shape[1]}")
                hp = pp[idx, :people].reshape(len(idx), 3 * people)
            f = np.concatenate([f, np.nan_to_num(hp, nan=0.0).astype(np.float32)], axis=1)
        return f
