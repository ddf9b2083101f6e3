"""The two evaluations of a compared method (the paper's protocol), with their floors.

* **dynamic** - unseen antenna positions x unseen person positions, against the ground truth
  with the person; nearest neighbour over (antenna, person) position among the training
  samples with a person. Methods without a person input render one image for every person.
* **static** - the background alone (person fields off; End-to-End with the "no person"
  input) at unseen antenna positions, against the empty room; nearest neighbour over the
  antenna position among the empty-room training samples.
* **fit** (in the static part) - the background at a subset of its own training positions
  (:data:`FIT_POSITIONS` of them, evenly spaced), against the empty room: test against fit
  is the model's generalisation gap (how much it overfits).
* **by distance** (in each part) - mean SSIM of the model and the neighbour floors per quartile
  of the distance to the fixed device and to the nearest training position
  (:func:`rfmitsuba.eval.breakdown.breakdown`): where the model breaks.
* **affected** - the dynamic evaluation restricted to the test PAS the person changes most
  (SSIM against the empty room's PAS at the same antenna below :data:`AFFECTED_SSIM`), with
  the empty room's own PAS as a third reference (the best any background-only model scores).

A model is anything with ``render(data, idx)`` and ``num_primitives``: a
:class:`~rfmitsuba.models.base.FieldSet`.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..core.errors import RunError
from ..core.ssim import ssim_images
from ..data.samples import SampleData
from ..data.store import open_dataset
from ..rf.bartlett_ref import normalize as minmax
from . import floor_cache
from .breakdown import breakdown, fixed_device
from .metrics import floors, stats

#: Training positions of the static part's fit (evenly spaced over the training samples).
FIT_POSITIONS = 180


def fit_rows(count: int) -> np.ndarray:
    """Rows of the fit: up to :data:`FIT_POSITIONS` of ``count`` training samples, evenly spaced
    (int64 [min(count, FIT_POSITIONS)], ascending)."""
    return np.unique(np.linspace(0, count - 1, min(FIT_POSITIONS, count)).astype(np.int64))


def test_sets(data: SampleData) -> dict:
    """Sample indices (into ``data`` opened with states="all") of both evaluations:
    ``dynamic_test``, ``dynamic_train`` (person-present training samples), ``static_test``,
    ``static_train``. The training sets are ``data``'s own (its training positions and walk,
    :meth:`SampleData.open_samples`); the test sets are the split's."""
    sp = data.split
    a_test = np.isin(data.antennas, sp.antenna_test)
    h_test = np.isin(data.states, np.asarray(sp.person_test) + 1)
    st0 = data.states == 0
    train = np.zeros(len(data.states), bool)
    train[data.train] = True
    return {"dynamic_test": np.flatnonzero(a_test & h_test), "dynamic_train": np.flatnonzero(train & ~st0),
            "static_test": np.flatnonzero(a_test & st0), "static_train": np.flatnonzero(train & st0)}


def evaluate(model, dataset: str | Path, *, batch: int = 8, keep: bool = False,
             noise_snr_db: float | None = None, noise_seed: int = 0,
             floors_cache: str | Path | None = None, train_antennas: int = 0, layout: str = "random",
             walk_frames: int | None = None) -> dict:
    """Both evaluations of ``model`` on ``dataset`` (metric protocol (docs/conventions.md), full 90 x 360).

    The floors look up the training samples the model saw: ``train_antennas``, ``layout`` and
    ``walk_frames`` as :meth:`rfmitsuba.data.samples.SampleData.open_samples` (default: the
    whole training split). A part without training samples (the dynamic part of a model trained
    on none of the walk, ``walk_frames=0``) has the model's figures only, no floors.

    Returns:
        {"dynamic": part, "static": part, "affected": dict or None, "render_ms_per_pas": float,
        "num_gaussians": int}, each part {"model", "nearest_neighbour", "idw3", "mean_image": stats
        dicts (mean, median, p10, min, n), "beats_nearest_neighbour": bool, "by_distance":
        :func:`~rfmitsuba.eval.breakdown.breakdown` of the model, nearest-neighbour and IDW-3 SSIM};
        the static part also "fit": stats of the model at :data:`FIT_POSITIONS` of its training
        positions (render time not counted in "render_ms_per_pas"); with ``keep`` also the
        per-image arrays (``*_ssim``) and images (``pred``, ``gt``). "affected" is the dynamic
        evaluation on the PAS the person changes most (:func:`_affected`).

        With ``noise_snr_db`` (a model trained on noisy data, :mod:`rfmitsuba.data.samples`, noise
        seed ``noise_seed``) each part also has "floors_noisy_training": the three floors computed
        from the same noisy training PAS the model saw ({"nearest_neighbour", "idw3", "mean_image"}
        stats dicts), against the same clean test PAS; the plain floors stay the clean ones.

        ``floors_cache``: a folder where the per-image floors are kept
        (:mod:`rfmitsuba.eval.floor_cache`, keyed by the dataset's fingerprint, the part and the
        noise), so every model evaluated on the same dataset reuses them; None computes them.
    """

    chosen = {"train_antennas": train_antennas, "layout": layout, "walk_frames": walk_frames}
    data = SampleData.open_samples(dataset, states="all", **chosen)
    fp = open_dataset(dataset, check=False).fingerprint() if floors_cache is not None else ""
    # the cache keys of the whole training split are those of before the choice existed
    picked = {} if chosen == {"train_antennas": 0, "layout": "random", "walk_frames": None} else {"train": chosen}
    noisy = (None if noise_snr_db is None else
             SampleData.open_samples(dataset, states="all", noise_snr_db=noise_snr_db, noise_seed=noise_seed,
                                     **chosen))
    sets = test_sets(data)
    fixed = fixed_device(data)
    out = {"num_gaussians": model.num_primitives}
    t_render, n_render = 0.0, 0
    for part, test_key, train_key, use_person in (("dynamic", "dynamic_test", "dynamic_train", True),
                                                 ("static", "static_test", "static_train", False)):
        test, train = sets[test_key], sets[train_key]
        if len(test) == 0:
            out[part] = None
            continue
        gt = data.pas(test)
        t0 = time.perf_counter()
        pred = minmax(model.render(data, test, batch=batch))
        t_render += time.perf_counter() - t0
        n_render += len(test)
        if not np.isfinite(pred).all():
            raise RunError(f"the model renders non-finite values ({part} evaluation of {dataset})")
        s_model = ssim_images(pred, gt)
        if len(train) == 0:   # nothing to look up: the model's figures alone
            out[part] = {"model": stats(s_model), "test_samples": int(len(test)), "train_samples": 0}
            if use_person:
                out["affected"] = _affected(data, test, gt, s_model, None, floors_cache=floors_cache, fingerprint=fp)
            continue
        person = {"train_person": data.person_pos[train] if use_person else None,
                 "test_person": data.person_pos[test] if use_person else None}
        fl = floor_cache.cached(
            floors_cache, {"floors": part, "dataset": fp, **picked},
            lambda: floors(data.pas_rows(train), data.antenna_pos[train], gt, data.antenna_pos[test], **person),
            length=len(test))
        res = {"model": stats(s_model), "nearest_neighbour": stats(fl["nearest_neighbour"]),
               "idw3": stats(fl["idw3"]), "mean_image": stats(fl["mean_image"]),
               "beats_nearest_neighbour": bool(s_model.mean() > fl["nearest_neighbour"].mean()),
               "test_samples": int(len(test)), "train_samples": int(len(train)),
               "by_distance": breakdown(data.antenna_pos[test], data.antenna_pos[train], fixed,
                                        {"model": s_model, "nearest_neighbour": fl["nearest_neighbour"],
                                         "idw3": fl["idw3"]})}
        if not use_person:   # the background at its own training positions: the generalisation gap
            fit = train[fit_rows(len(train))]
            res["fit"] = stats(ssim_images(minmax(model.render(data, fit, batch=batch)), data.pas(fit)))
        if noisy is not None:   # the floors a lookup in the same noisy training data reaches
            fn = floor_cache.cached(
                floors_cache, {"floors_noisy_training": part, "dataset": fp, "snr_db": float(noise_snr_db),
                               "noise_seed": int(noise_seed), **picked},
                lambda: floors(noisy.pas_rows(train), data.antenna_pos[train], gt, data.antenna_pos[test], **person),
                length=len(test))
            res["floors_noisy_training"] = {k: stats(fn[k]) for k in ("nearest_neighbour", "idw3", "mean_image")}
        if keep:
            res.update({"model_ssim": s_model, "nn_ssim": fl["nearest_neighbour"], "pred": pred, "gt": gt,
                        "nn": data.pas(train)[fl["nearest_index"]]})
        out[part] = res
        if use_person:
            out["affected"] = _affected(data, test, gt, s_model, fl["nearest_neighbour"],
                                        floors_cache=floors_cache, fingerprint=fp)
    out["render_ms_per_pas"] = 1000 * t_render / max(n_render, 1)
    return out


#: A dynamic test PAS is *affected* by the person when its SSIM against the empty room's PAS at
#: the same antenna position is below this.
AFFECTED_SSIM = 0.9


def _affected(data: SampleData, test: np.ndarray, gt: np.ndarray, s_model: np.ndarray, s_nn: np.ndarray, *,
              floors_cache: str | Path | None = None, fingerprint: str = "") -> dict | None:
    """The dynamic evaluation restricted to the test PAS the person changes most.

    Args:
        data: samples opened with states="all"; test: int [K] dynamic test sample indices;
        gt: float [K, H, W] their ground truth; s_model / s_nn: float [K] per-PAS SSIM of the model
        and of the nearest-neighbour floor (None: no floor, the model saw no sample with the
        person); floors_cache, fingerprint: as :func:`evaluate` (the empty room's SSIM is cached
        with the floors).

    Returns:
        None when no test PAS is affected (SSIM against the empty room < :data:`AFFECTED_SSIM`
        for none), else {"model", "nearest_neighbour", "empty_room": stats dicts over the affected
        PAS ("empty_room" = the empty room's true PAS used as the prediction: what a perfect
        background model scores), "threshold", "fraction" (affected / all dynamic test PAS)}.
    """

    empty = {int(a): int(k) for k, a in enumerate(data.antennas) if data.states[k] == 0}
    ref = np.array([empty.get(int(a), -1) for a in data.antennas[test]])
    if (ref < 0).any():
        return None
    s_empty = floor_cache.cached(floors_cache, {"empty_room": "dynamic", "dataset": fingerprint},
                                 lambda: {"ssim": ssim_images(data.pas(ref), gt)}, length=len(test))["ssim"]
    mask = s_empty < AFFECTED_SSIM
    if not mask.any():
        return None
    out = {"model": stats(s_model[mask]), "empty_room": stats(s_empty[mask]), "threshold": AFFECTED_SSIM,
           "fraction": float(mask.mean())}
    if s_nn is not None:
        out["nearest_neighbour"] = stats(s_nn[mask])
    return out
