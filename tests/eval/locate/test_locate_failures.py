"""rfmitsuba.eval.locate.failures: the geometric proxies of a hard position."""
from __future__ import annotations

import numpy as np
import pytest


def test_failure_proxies_blocked_path():
    from rfmitsuba.eval.locate import failure_proxies

    y = np.array([[0.0, 0.0, 1.0]] * 2)
    x = np.array([[4.0, 0.0, 1.0], [0.0, 4.0, 1.0]])
    p = failure_proxies(np.array([2.0, 0.1, 0.0]), x, y)
    assert p["blocked_share"] == 0.5 and p["hidden_from_tx"] is None
    assert p["distance_to_array_m"] == pytest.approx(np.hypot(2.0, 0.1))
