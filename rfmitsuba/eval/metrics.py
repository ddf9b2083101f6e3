"""The metric protocol's statistics and the model-free floors.

Every predicted and true PAS is min-max normalised on its own and compared by
:func:`rfmitsuba.core.ssim.ssim_images` per image. Floors on the same split, from
:func:`floors`: **nearest neighbour** (:func:`nearest_index`: the training PAS whose antenna
position - and person position, where given - is nearest), **IDW-3** (:func:`idw_predict`:
the inverse-distance-weighted mean of the 3 nearest training PAS, min-max normalised; where
positions are dense it beats nearest neighbour) and **mean image** (the mean of the
normalised training PAS). :func:`best_floor` names the higher of the two neighbour floors. :func:`stats` summarises per-image SSIM (mean, median, p10, min,
n); :func:`mean_std` gives mean and standard deviation over seeds.
"""
from __future__ import annotations

import math

import numpy as np

from ..core.ssim import ssim_images
from ..data.views import PAS_CHUNK
from ..rf.bartlett_ref import normalize as minmax


def _joint(pos, person):
    """Positions [N, 3], joined with person positions [N, 3] into 6-D points where given (NaN
    rows, the empty room, count as a person far away)."""
    a = np.asarray(pos, np.float64)
    if person is None:
        return a
    return np.concatenate([a, np.nan_to_num(np.asarray(person, np.float64), nan=1e3)], 1)


def nearest_index(train_pos: np.ndarray, query_pos: np.ndarray, *, train_person: np.ndarray | None = None,
                  query_person: np.ndarray | None = None) -> np.ndarray:
    """Index of the nearest training sample for every query.

    Distance: Euclidean over the antenna position (metres), plus the person position
    where both are given (6-D distance; NaN person rows, i.e. empty room, count as a person
    far away from any real position).

    Args:
        train_pos: float [M, 3] metres; query_pos: float [K, 3] metres.
        train_person / query_person: float [M, 3] / [K, 3] metres or None.

    Returns:
        int64 [K] indices into the training rows (ties: the lowest index).
    """
    from scipy.spatial import cKDTree

    both = train_person is not None and query_person is not None
    a = _joint(train_pos, train_person if both else None)
    q = _joint(query_pos, query_person if both else None)
    if len(a) == 0:
        raise ValueError("nearest_index: no training samples")
    _, idx = cKDTree(a).query(q, k=1)
    return np.asarray(idx, dtype=np.int64)


def neighbour_weights(train_pos: np.ndarray, query_pos: np.ndarray, *, k: int,
                      train_person: np.ndarray | None = None, query_person: np.ndarray | None = None) -> tuple:
    """The ``k`` nearest training samples of every query and their inverse-distance weights.

    Args:
        train_pos: float [M, 3] metres; query_pos: float [K, 3] metres; train_person /
        query_person: optional [M, 3] / [K, 3] metres (6-D distance as :func:`nearest_index`).
        k: neighbours (at most M). Weights are 1 / distance, normalised; a query on a training
        position takes that sample alone.

    Returns:
        (idx int64 [K, k], w float64 [K, k] summing to 1 per row).
    """
    from scipy.spatial import cKDTree

    both = train_person is not None and query_person is not None
    a = _joint(train_pos, train_person if both else None)
    q = _joint(query_pos, query_person if both else None)
    if len(a) == 0:
        raise ValueError("neighbour_weights: no training samples")
    k = min(int(k), len(a))
    dist, idx = cKDTree(a).query(q, k=k)
    dist, idx = dist.reshape(len(q), k), idx.reshape(len(q), k)
    w = 1.0 / np.maximum(dist, 1e-9)
    exact = dist[:, :1] <= 1e-9
    w = np.where(exact, (dist <= 1e-9).astype(np.float64), w)
    return np.asarray(idx, np.int64), w / w.sum(1, keepdims=True)


def idw_predict(train_pas: np.ndarray, train_pos: np.ndarray, query_pos: np.ndarray, *, k: int = 3,
                train_person: np.ndarray | None = None, query_person: np.ndarray | None = None) -> np.ndarray:
    """Inverse-distance-weighted mean of the ``k`` nearest training PAS (:func:`neighbour_weights`),
    min-max normalised.

    Args:
        train_pas: float [M, H, W] normalised training PAS; train_pos: float [M, 3] metres;
        query_pos: float [K, 3] metres; train_person / query_person: as :func:`neighbour_weights`.

    Returns:
        float32 [K, H, W] in [0, 1].
    """
    idx, w = neighbour_weights(train_pos, query_pos, k=k, train_person=train_person, query_person=query_person)
    return _idw_images(train_pas, idx, w)


def _idw_images(train_pas, idx: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Min-max normalised weighted means of training rows ``idx`` (int [K, k]) with weights ``w``
    ([K, k]), reading only those rows of ``train_pas`` (an array or a row reader): float32 [K, H, W]."""
    rows, inverse = np.unique(idx.ravel(), return_inverse=True)
    return _weighted_images(np.asarray(train_pas[rows], np.float32)[inverse.reshape(idx.shape)], w)


def _weighted_images(near: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Min-max normalised weighted means of ``near`` (float [K, k, H, W]) with weights ``w``
    ([K, k]): float32 [K, H, W]."""
    out = np.einsum("kn,knhw->khw", w.astype(np.float32), near)
    return minmax(out).astype(np.float32)


def mean_training_image(train_pas) -> np.ndarray:
    """The mean of the training PAS, min-max normalised: float64 [1, H, W].

    Args:
        train_pas: float [M, H, W] normalised PAS, or a row reader (``len()``, and ``[idx]`` for
            int64 [k] giving [k, H, W]), read :data:`~rfmitsuba.data.views.PAS_CHUNK` rows at a time.

    The rows are added one after another in float64, the order of ``mean(axis=0)``, so the result
    equals the mean of the whole array held at once, without holding it (a walk dataset's 20 000
    training PAS are 2.6 GB as float32, 5.2 GB as float64).
    """
    m = len(train_pas)
    if m == 0:
        raise ValueError("mean_training_image: no training samples")
    acc = None
    for a in range(0, m, PAS_CHUNK):
        for row in np.asarray(train_pas[np.arange(a, min(a + PAS_CHUNK, m))], np.float64):
            if acc is None:
                acc = row.copy()
            else:
                np.add(acc, row, out=acc)
    return minmax((acc / m)[None])


def floors(train_pas, train_pos: np.ndarray, test_pas: np.ndarray, test_pos: np.ndarray, *,
           train_person=None, test_person=None) -> dict:
    """Model-free baselines on one split.

    Args:
        train_pas: float [M, H, W] normalised training PAS, or a row reader of them (``len()``, and
            ``[idx]`` for int64 [k] giving [k, H, W]: :meth:`rfmitsuba.data.samples.SampleData.pas_rows`),
            of which only the rows the neighbour floors use are read, and all rows once in chunks
            for the mean image. The test images are taken :data:`~rfmitsuba.data.views.PAS_CHUNK`
            at a time with their neighbours' rows (the same values as all at once).
        train_pos: float [M, 3] metres.
        test_pas: float [K, H, W] normalised test PAS; test_pos: float [K, 3] metres.
        train_person / test_person: optional person positions [M, 3] / [K, 3].

    Returns:
        {"nearest_neighbour": float64 [K] SSIM, "nearest_index": int64 [K],
         "idw3": float64 [K] SSIM of :func:`idw_predict` (k = 3), "mean_image": float64 [K] SSIM}.
    """
    idx = nearest_index(train_pos, test_pos, train_person=train_person, query_person=test_person)
    idw_idx, idw_w = neighbour_weights(train_pos, test_pos, k=3, train_person=train_person, query_person=test_person)
    mean_img = mean_training_image(train_pas)
    k = len(test_pas)
    out = {"nearest_neighbour": np.empty(k), "nearest_index": idx, "idw3": np.empty(k), "mean_image": np.empty(k)}
    # a chunk of test images at a time: the neighbours' images of 10 000 test PAS are 5.2 GB
    for a in range(0, k, PAS_CHUNK):
        b = min(a + PAS_CHUNK, k)
        gt = np.asarray(test_pas[a:b])
        # the nearest neighbour is one of the three: their rows are read once for both floors
        rows, inverse = np.unique(np.concatenate([idx[a:b], idw_idx[a:b].ravel()]), return_inverse=True)
        near = np.asarray(train_pas[rows])[inverse]
        idw = _weighted_images(near[b - a:].astype(np.float32).reshape(b - a, idw_idx.shape[1], *near.shape[1:]),
                               idw_w[a:b])
        out["nearest_neighbour"][a:b] = ssim_images(near[:b - a], gt)
        out["idw3"][a:b] = ssim_images(idw, gt)
        out["mean_image"][a:b] = ssim_images(np.broadcast_to(mean_img, gt.shape), gt)
    return out


def best_floor(metrics: dict) -> tuple[str, dict]:
    """The higher-scoring (mean SSIM) neighbour floor of an evaluation dict holding the stats
    dicts "nearest_neighbour" and, where computed, "idw3": (key, stats)."""
    keys = [k for k in ("nearest_neighbour", "idw3") if metrics.get(k)]
    k = max(keys, key=lambda key: metrics[key]["mean"])
    return k, metrics[k]


def stats(x: np.ndarray) -> dict:
    """Mean, median, 10th percentile, min of per-image SSIM."""
    x = np.asarray(x, np.float64)
    return {"mean": float(x.mean()), "median": float(np.median(x)), "p10": float(np.percentile(x, 10)),
            "min": float(x.min()), "n": int(len(x))}


def mean_std(values: list[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (0 for one value; NaN for none)."""
    v = [x for x in values if x is not None and math.isfinite(x)]
    if not v:
        return float("nan"), float("nan")
    return float(np.mean(v)), float(np.std(v, ddof=1)) if len(v) > 1 else 0.0
