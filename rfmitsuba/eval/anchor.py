"""Neighbour-anchored prediction: the measured spectra of the nearest training positions plus a
trained field's *change* from them to the query.

A field that draws the right physics can still miss a measured spectrum by what it does not
model (diffuse scattering, the array's real patterns, calibration left over); a lookup of the
nearest training spectrum carries all of that but not the change with position. The anchored
prediction combines the two, as GRaF conditions a field on the spectra of neighbouring
transmitters:

    P(q) = minmax( max(0, sum_i w_i T_i + alpha * (F(q) - sum_i w_i F(q_i))) )

with ``T_i`` the normalised training PAS at the ``k`` nearest training positions ``q_i``, ``w_i``
their inverse-distance weights (:func:`rfmitsuba.eval.metrics.neighbour_weights`; ``k = 3``,
``alpha = 0`` is the IDW-3 floor itself) and ``F`` the field's normalised render. ``alpha = 1``
trusts the field's differences fully.

``(k, alpha)`` are chosen by :func:`choose` on the run's **validation positions**, which the
trainer held out of fitting (drawn at random among the training positions), with anchors from the fitting positions only: no test spectrum
chooses them. The field alone is a candidate too; choosing ``alpha = 0`` says the field's
changes do not help beyond the lookup.
"""
from __future__ import annotations

import numpy as np

from ..core.ssim import ssim_images
from ..rf.bartlett_ref import normalize as minmax
from .metrics import neighbour_weights

#: the neighbour counts and field weights :func:`choose` tries
KS = (1, 3)
ALPHAS = (0.0, 0.25, 0.5, 0.75, 1.0)


def anchored(field_query: np.ndarray, field_pool: np.ndarray, pas_pool: np.ndarray, pool_pos: np.ndarray,
             query_pos: np.ndarray, *, k: int, alpha: float) -> np.ndarray:
    """The anchored prediction (module docstring).

    Args:
        field_query: float [K, H, W] the field's normalised PAS at the queries.
        field_pool: float [M, H, W] the field's normalised PAS at the pool (training) positions.
        pas_pool: float [M, H, W] the pool's normalised measured PAS.
        pool_pos: float [M, 3], query_pos: float [K, 3] the moving device's positions [m].
        k: neighbours (>= 1); alpha: weight of the field's change (>= 0).

    Returns:
        float32 [K, H, W] in [0, 1].
    """
    if k < 1 or alpha < 0:
        raise ValueError(f"anchored: k >= 1 and alpha >= 0 required, got k={k}, alpha={alpha}")
    fq, fp, tp = (np.asarray(a, np.float32) for a in (field_query, field_pool, pas_pool))
    if fp.shape != tp.shape or fq.shape[1:] != tp.shape[1:] or len(fq) != len(query_pos) \
            or len(tp) != len(pool_pos):
        raise ValueError(f"anchored: shapes differ: query {fq.shape} for {len(query_pos)} positions, "
                         f"pool {fp.shape} / {tp.shape} for {len(pool_pos)} positions")
    idx, w = neighbour_weights(pool_pos, query_pos, k=k)
    w = w.astype(np.float32)
    out = np.einsum("qn,qnhw->qhw", w, tp[idx]) + alpha * (fq - np.einsum("qn,qnhw->qhw", w, fp[idx]))
    return minmax(np.maximum(out, 0.0)).astype(np.float32)


def choose(field_val: np.ndarray, field_fit: np.ndarray, pas_fit: np.ndarray, fit_pos: np.ndarray,
           val_pos: np.ndarray, pas_val: np.ndarray) -> dict:
    """The best of the field alone and the ``(k, alpha)`` of :data:`KS` x :data:`ALPHAS` by mean
    SSIM on the validation positions, anchored on the fitting positions (arrays as
    :func:`anchored`).

    Returns:
        {"use": "field" or "anchored", "k", "alpha" (of the best anchored choice), "val_ssim": the
         chosen prediction's mean validation SSIM, "field_val_ssim": the field alone's,
         "grid": {"k=K alpha=A": mean SSIM}}.
    """
    grid = {}
    for k in KS:
        for a in ALPHAS:
            pred = anchored(field_val, field_fit, pas_fit, fit_pos, val_pos, k=k, alpha=a)
            grid[(k, a)] = float(ssim_images(pred, pas_val).mean())
    (k, a), best = max(grid.items(), key=lambda kv: (kv[1], -kv[0][1]))   # ties: the smaller alpha
    alone = float(ssim_images(minmax(np.asarray(field_val, np.float32)), pas_val).mean())
    return {"use": "field" if alone >= best else "anchored", "k": int(k), "alpha": float(a),
            "val_ssim": max(alone, best), "field_val_ssim": alone,
            "grid": {f"k={kk} alpha={aa}": v for (kk, aa), v in grid.items()}}
