"""Tests of rfmitsuba.eval.metrics (and the SSIM of rfmitsuba.core.ssim it uses): the protocol,
the three floors on hand-made cases, statistics."""
from __future__ import annotations

import numpy as np
import pytest


def _img(seed, h=20, w=30):
    return np.random.default_rng(seed).random((h, w)).astype(np.float32)


def test_ssim_images_is_skimage_per_image():
    from skimage.metrics import structural_similarity

    from rfmitsuba.core.ssim import ssim_images

    a = np.stack([_img(0), _img(1)])
    b = np.stack([_img(0), _img(2)])
    s = ssim_images(a, b)
    assert s[0] == pytest.approx(1.0)
    assert s[1] == pytest.approx(structural_similarity(a[1].astype(np.float64), b[1].astype(np.float64),
                                                       data_range=1.0))
    with pytest.raises(ValueError, match="must both be"):
        ssim_images(a, b[:1])


def test_nearest_index_with_and_without_person():
    from rfmitsuba.eval.metrics import nearest_index

    train = np.array([[0, 0, 0], [1, 0, 0], [5, 5, 1.0]])
    q = np.array([[0.9, 0.1, 0], [4, 4, 1], [0.2, 0, 0]])
    np.testing.assert_array_equal(nearest_index(train, q), [1, 2, 0])
    # with person positions the nearest sample is the one with the closer person
    train2 = np.array([[0, 0, 0], [0, 0, 0.0]])
    th = np.array([[3, 3, 0], [1, 1, 0.0]])
    np.testing.assert_array_equal(nearest_index(train2, np.zeros((1, 3)), train_person=th,
                                                query_person=np.array([[1.2, 1, 0]])), [1])


def test_floors_on_hand_made_cases():
    """Test image k equals training image k, placed at the training position plus 1 cm: the
    nearest-neighbour floor is exactly 1; the mean-image floor compares with the normalised mean."""
    from rfmitsuba.core.ssim import ssim_images
    from rfmitsuba.eval.metrics import floors
    from rfmitsuba.rf.bartlett_ref import normalize as minmax

    train = minmax(np.stack([_img(i) for i in range(4)]))
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    test = train[[2, 0]]
    f = floors(train, pos, test, pos[[2, 0]] + 0.01)
    np.testing.assert_allclose(f["nearest_neighbour"], 1.0)
    np.testing.assert_array_equal(f["nearest_index"], [2, 0])
    mean = minmax(train.mean(0)[None])[0]
    np.testing.assert_allclose(f["mean_image"], ssim_images(np.stack([mean, mean]), test))
    assert np.all(f["mean_image"] < 0.9)


def test_minmax_and_stats():
    from rfmitsuba.eval.metrics import stats
    from rfmitsuba.rf.bartlett_ref import normalize as minmax

    x = np.stack([np.full((3, 3), 5.0), np.arange(9.0).reshape(3, 3)])
    m = minmax(x)
    assert m[0].max() == 0 and m[1].min() == 0 and m[1].max() == 1
    s = stats(np.array([0.1, 0.5, 0.9, 0.3]))
    assert s["mean"] == pytest.approx(0.45) and s["median"] == pytest.approx(0.4) and s["n"] == 4


def test_idw3_weights_by_inverse_distance():
    """Hand-made: two training images at distances 1 and 3 from the query (k = 2) mix 3:1 before
    normalisation; a query on a training position returns that image; the floor dict has idw3."""
    from rfmitsuba.eval.metrics import floors, idw_predict
    from rfmitsuba.rf.bartlett_ref import normalize as minmax

    a = np.zeros((1, 4, 4), np.float32)
    a[0, 0, 0] = 1.0
    b = np.zeros((1, 4, 4), np.float32)
    b[0, 3, 3] = 1.0
    train = np.concatenate([a, b])
    pos = np.array([[1.0, 0, 0], [-3.0, 0, 0]])
    got = idw_predict(train, pos, np.zeros((1, 3)), k=2)[0]
    want = minmax((0.75 * a[0] + 0.25 * b[0])[None])[0]
    np.testing.assert_allclose(got, want, atol=1e-6)
    np.testing.assert_allclose(idw_predict(train, pos, pos[1:], k=2)[0], b[0])
    # k larger than the training set is clipped; a person position joins the distance
    got6 = idw_predict(train, np.zeros((2, 3)), np.zeros((1, 3)), k=3, train_person=pos, query_person=np.zeros((1, 3)))
    np.testing.assert_allclose(got6[0], want, atol=1e-6)
    t4 = minmax(np.stack([_img(i) for i in range(4)]))
    f = floors(t4, np.eye(4, 3), t4[:2], np.eye(4, 3)[:2])
    np.testing.assert_allclose(f["idw3"], 1.0)  # test positions on training ones: exact


def test_floors_from_a_row_reader_equal_floors_from_the_array(monkeypatch):
    """A row reader (PasRows) gives the same floors bit for bit as the whole array: the neighbour
    floors read only their rows, and the mean image reads every row once, a chunk at a time, adding
    rows in the order of mean(axis=0); a person position joins the distance either way."""
    from rfmitsuba.data.views import PasRows
    from rfmitsuba.eval import metrics
    from rfmitsuba.rf.bartlett_ref import normalize as minmax

    rng = np.random.default_rng(3)
    m, k = 37, 6
    train = minmax(rng.random((m, 9, 12)).astype(np.float32))
    test = minmax(rng.random((k, 9, 12)).astype(np.float32))
    pos, qpos = rng.random((m, 3)), rng.random((k, 3))
    hum, qhum = rng.random((m, 3)), rng.random((k, 3))
    rows = np.arange(100, 100 + m)            # the reader's samples are not 0..m-1
    reads = []

    def read(samples):
        reads.append(np.asarray(samples).copy())
        return train[samples - 100]

    monkeypatch.setattr(metrics, "PAS_CHUNK", 8)
    whole = metrics.floors(train, pos, test, qpos, train_person=hum, test_person=qhum)
    lazy = metrics.floors(PasRows(rows=rows, read=read), pos, test, qpos, train_person=hum, test_person=qhum)
    for key in whole:
        np.testing.assert_array_equal(lazy[key], whole[key])
    np.testing.assert_array_equal(metrics.mean_training_image(train), minmax(train.astype(np.float64).mean(0)[None]))
    sizes = [len(r) for r in reads]
    assert max(sizes) <= max(8, 3 * k)                     # never the whole array at once
    assert sum(sizes[:5]) == m and sizes[:5] == [8, 8, 8, 8, 5]    # the mean image's chunks
    assert len(sizes) == 6 and sizes[5] <= 3 * k              # the neighbour floors' rows, read once
    with pytest.raises(IndexError, match="int array"):
        PasRows(rows=rows, read=read)[3]


def test_floors_over_test_chunks_equal_floors_in_one_pass(monkeypatch):
    """The floors run a chunk of test images at a time (the neighbours' images of a walk's
    10 000 test PAS are 5.2 GB at once): the same values bit for bit as one chunk, and a chunk
    reads only its own neighbours' rows."""
    from rfmitsuba.data.views import PasRows
    from rfmitsuba.eval import metrics
    from rfmitsuba.rf.bartlett_ref import normalize as minmax

    rng = np.random.default_rng(5)
    m, k = 40, 21
    train = minmax(rng.random((m, 9, 12)).astype(np.float32))
    test = minmax(rng.random((k, 9, 12)).astype(np.float32))
    pos, qpos = rng.random((m, 3)), rng.random((k, 3))
    one = metrics.floors(train, pos, test, qpos)
    reads = []

    def read(samples):
        reads.append(np.asarray(samples).copy())
        return train[samples]

    monkeypatch.setattr(metrics, "PAS_CHUNK", 8)
    chunked = metrics.floors(PasRows(rows=np.arange(m), read=read), pos, test, qpos)
    for key in one:
        np.testing.assert_array_equal(chunked[key], one[key])
    neighbour_reads = [len(r) for r in reads[5:]]             # after the mean image's 5 chunks
    assert len(neighbour_reads) == 3 and all(n <= 3 * 8 for n in neighbour_reads)   # 8 + 8 + 5 test images


def test_best_floor_names_the_higher_neighbour_floor():
    from rfmitsuba.eval.metrics import best_floor

    m = {"nearest_neighbour": {"mean": 0.5}, "idw3": {"mean": 0.6}, "mean_image": {"mean": 0.9}}
    assert best_floor(m)[0] == "idw3"
    assert best_floor({"nearest_neighbour": {"mean": 0.5}})[0] == "nearest_neighbour"
