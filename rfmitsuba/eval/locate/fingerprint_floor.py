"""The fingerprint floor: the training walk state whose measured PAS at the query's antennas are
most like the query's."""
from __future__ import annotations

import numpy as np

from ...data.samples import SampleData
from ...rf.bartlett_ref import normalize as minmax
from .query import VIEWS_PER_CALL


def fingerprint(data: SampleData, query_pas: np.ndarray, antennas: np.ndarray, *, states: np.ndarray) -> dict:
    """The fingerprint floor: of the dataset states ``states`` (int [S], person states), the one
    whose measured PAS at ``antennas`` (int [K] antenna indices) are most like ``query_pas``
    (float [K, 90, 360], normalised): highest mean SSIM over the K PAS (Dr.Jit float32 SSIM,
    skimage's definition). Returns {"state": int, "position": float64 [3], "ssim": float}."""
    import drjit as dr

    from ...core import backend as B
    from ...train import loss as L

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
