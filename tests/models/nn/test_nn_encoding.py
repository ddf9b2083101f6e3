"""Tests of rfmitsuba.models.nn.encoding: the positional encodings."""
from __future__ import annotations

import numpy as np


def test_sin_encoding_matches_numpy(variant):
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.nn import encode

    x = np.array([0.0, 0.1, 0.37, 0.5], np.float32)
    out = encode([B.Float(x)], octaves=3)
    assert len(out) == 1 + 2 * 3
    np.testing.assert_allclose(out[0].numpy(), x)
    for k in range(3):
        np.testing.assert_allclose(out[1 + 2 * k].numpy(), np.sin(2 * np.pi * 2 ** k * x), atol=2e-5)
        np.testing.assert_allclose(out[2 + 2 * k].numpy(), np.cos(2 * np.pi * 2 ** k * x), atol=2e-5)
