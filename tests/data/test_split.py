"""Tests of rfmitsuba.data.split: the seeded random split and the spatial-block split."""
import numpy as np
import pytest

from rfmitsuba.core.errors import DatasetError
from rfmitsuba.data.split import block_split, make_split


def test_block_split_holds_out_the_slab_of_largest_x():
    rng = np.random.default_rng(0)
    pos = rng.random((200, 3)) * [1.6, 1.3, 0.9]
    train, test = block_split(pos)
    assert len(test) == 40 and len(train) == 160
    assert np.intersect1d(train, test).size == 0 and np.union1d(train, test).size == 200
    assert pos[test, 0].min() > pos[train, 0].max()
    tr_y, te_y = block_split(pos, fraction=0.1, axis=1)
    assert len(te_y) == 20 and pos[te_y, 1].min() > pos[tr_y, 1].max()


def test_block_split_ties_go_to_the_test_side_and_bad_input_is_named():
    pos = np.zeros((10, 3))
    pos[:, 0] = [0, 1, 2, 3, 4, 5, 6, 7, 7, 7]
    train, test = block_split(pos)  # 2 asked, 3 tied at x = 7
    assert sorted(test) == [7, 8, 9] and pos[test, 0].min() > pos[train, 0].max()
    with pytest.raises(DatasetError, match="share coordinate 0"):
        block_split(np.ones((5, 3)))
    with pytest.raises(DatasetError, match=r"\[A >= 2, 3\]"):
        block_split(np.ones((5, 2)))
    with pytest.raises(DatasetError, match="fraction"):
        block_split(pos, fraction=1.5)


def test_make_split_is_seeded():
    a, b = make_split(100, 0, seed=1), make_split(100, 0, seed=1)
    assert np.array_equal(a.antenna_test, b.antenna_test) and len(a.antenna_test) == 20
