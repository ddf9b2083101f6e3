"""Tests of rfmitsuba.core.encoding: the sine-cosine encoding of the fields' networks."""
import numpy as np

from rfmitsuba.core.encoding import sin_encoding


def test_layout_and_values():
    x01 = np.array([[0.0, 0.5, 1.0], [0.25, 0.75, 0.1]])
    enc = sin_encoding(x01, 3)
    assert enc.shape == (2, 3 * (1 + 2 * 3)) and enc.dtype == np.float32
    x = 0.5 * x01
    np.testing.assert_allclose(enc[:, :3], x, atol=1e-7)
    for k in range(3):   # octave k: sines then cosines of 2 pi 2^k x, one column per input
        f = 2 * np.pi * 2 ** k
        np.testing.assert_allclose(enc[:, 3 + 6 * k:6 + 6 * k], np.sin(f * x), atol=1e-6)
        np.testing.assert_allclose(enc[:, 6 + 6 * k:9 + 6 * k], np.cos(f * x), atol=1e-6)


def test_no_octaves_is_the_halved_input():
    x01 = np.random.default_rng(0).random((5, 2))
    np.testing.assert_allclose(sin_encoding(x01, 0), 0.5 * x01, atol=1e-7)


def test_the_box_does_not_alias():
    """The lowest octave's cosine falls monotonically across the box [0, 1], so no two positions
    of the box share an encoding (without the halving, 0 and 1 would)."""
    x01 = np.linspace(0.0, 1.0, 101)[:, None]
    c = sin_encoding(x01, 4)[:, 2]
    assert np.all(np.diff(c) < 0)
    assert len(np.unique(sin_encoding(x01, 4).round(5), axis=0)) == 101
