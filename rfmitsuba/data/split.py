"""Train/test splits of a dataset: which antenna positions and which person (walk) positions
are held out for testing.

:func:`make_split` draws ``ANTENNA_TEST_FRACTION`` of the antenna positions and
``PERSON_TEST_FRACTION`` of the walk positions as test positions from a seeded generator;
:func:`block_split` holds out a slab instead (the positions with the largest x), so that test
positions lie away from every training one (docs/conventions.md, "Splits");
:class:`Split` holds the index lists and round-trips to ``split.json``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import DatasetError
from ..core.legacy_names import current_keys

#: Fractions of held-out antenna and person positions (docs/conventions.md, "Splits").
ANTENNA_TEST_FRACTION = 0.2


PERSON_TEST_FRACTION = 0.19


@dataclass(frozen=True)
class Split:
    """Train/test indices (int64, sorted): antenna ones index [0, A), person ones index [0, H).

    Person index ``h`` is dataset state ``h + 1``.
    """

    antenna_train: np.ndarray
    antenna_test: np.ndarray
    person_train: np.ndarray
    person_test: np.ndarray
    seed: int = 0

    def to_json(self) -> dict:
        return {
            "seed": int(self.seed),
            "antenna_test_fraction": ANTENNA_TEST_FRACTION,
            "person_test_fraction": PERSON_TEST_FRACTION,
            "antenna_train": [int(i) for i in self.antenna_train],
            "antenna_test": [int(i) for i in self.antenna_test],
            "person_train": [int(i) for i in self.person_train],
            "person_test": [int(i) for i in self.person_test],
        }

    @classmethod
    def from_json(cls, d: dict, *, num_antennas: int, num_people: int, where: str = "split.json") -> "Split":
        d = current_keys(d)   # split.json files written when the walk's keys said "human"
        try:
            arrs = {k: np.asarray(d[k], dtype=np.int64) for k in
                    ("antenna_train", "antenna_test", "person_train", "person_test")}
            seed = int(d.get("seed", 0))
        except (KeyError, TypeError, ValueError) as e:
            raise DatasetError(f"{where}: missing or malformed key {e}") from None
        for key, n in (("antenna", num_antennas), ("person", num_people)):
            both = np.concatenate([arrs[f"{key}_train"], arrs[f"{key}_test"]])
            if both.size and (both.min() < 0 or both.max() >= n):
                raise DatasetError(f"{where}: {key} indices outside [0, {n})")
            if len(np.unique(both)) != both.size:
                raise DatasetError(f"{where}: {key} train and test indices overlap or repeat")
        return cls(**arrs, seed=seed)


def make_split(num_antennas: int, num_people: int, *, seed: int = 0) -> Split:
    """Seeded split (docs/conventions.md): 20% of antenna positions and ~19% of person positions held out.

    Args:
        num_antennas: A, number of antenna positions.
        num_people: H, number of person positions (states minus the empty one).
        seed: RNG seed.
    """
    rng = np.random.default_rng(seed)
    perm_a = rng.permutation(num_antennas)
    n_at = int(round(ANTENNA_TEST_FRACTION * num_antennas)) if num_antennas > 1 else 0
    perm_h = rng.permutation(num_people)
    n_ht = int(round(PERSON_TEST_FRACTION * num_people)) if num_people > 1 else 0
    return Split(antenna_train=np.sort(perm_a[n_at:]).astype(np.int64),
                 antenna_test=np.sort(perm_a[:n_at]).astype(np.int64),
                 person_train=np.sort(perm_h[n_ht:]).astype(np.int64),
                 person_test=np.sort(perm_h[:n_ht]).astype(np.int64), seed=seed)


def block_split(positions: np.ndarray, *, fraction: float = ANTENNA_TEST_FRACTION, axis: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Spatial-block split: the ``fraction`` of positions with the largest coordinate ``axis``
    (0 = x) are the test set.

    Args:
        positions: float [A, 3] metres.
        fraction: share held out, in (0, 1).
        axis: 0, 1 or 2 (x, y, z).

    Returns:
        (train, test): int64 indices into ``positions``, sorted. Positions tied at the boundary all
        go to the test side, so every test position lies strictly beyond every training one along
        ``axis`` (DatasetError when all positions share that coordinate).
    """
    pos = np.asarray(positions, np.float64)
    if pos.ndim != 2 or pos.shape[1] != 3 or len(pos) < 2:
        raise DatasetError(f"block_split: positions must be [A >= 2, 3], got {pos.shape}")
    if not 0 < fraction < 1 or axis not in (0, 1, 2):
        raise DatasetError(f"block_split: fraction must be in (0, 1) and axis 0, 1 or 2, got {fraction}, {axis}")
    c = pos[:, axis]
    n_test = max(1, int(round(fraction * len(pos))))
    cut = np.sort(c)[len(c) - n_test]
    test = np.flatnonzero(c >= cut)
    if len(test) == len(c):
        raise DatasetError(f"block_split: all positions share coordinate {axis}; a slab cannot be held out")
    train = np.setdiff1d(np.arange(len(c)), test)
    return train.astype(np.int64), np.sort(test).astype(np.int64)
