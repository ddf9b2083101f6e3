"""rfmitsuba.eval.locate.query: the loss's AD gradient in the person's position against finite
differences, and the PAS files a query reads."""
from __future__ import annotations

import numpy as np
import pytest

from rfmitsuba.core.errors import DatasetError


def test_ad_gradient_matches_finite_differences(known_model, one_thread, pas_at, true_feet):
    from rfmitsuba.eval.locate import Query

    ant = known_model.data.antenna_pos[:3]
    q = Query(known_model, pas_at(known_model, true_feet, ant), ant, downsample=3)
    xy = true_feet[None, :2] + [[0.12, -0.08]]
    _, g = q.loss_and_grad(xy)
    h = 1e-3
    fd = [(q.losses(xy + d)[0] - q.losses(xy - d)[0]) / (2 * h) for d in (np.array([[h, 0]]), np.array([[0, h]]))]
    # the min-max normalisation's extreme pixels switch within millimetres, so the finite
    # differences scatter by some 20% along x: direction and size, not digits
    cos = float(g[0] @ fd / np.linalg.norm(g[0]) / np.linalg.norm(fd))
    assert cos > 0.98 and 0.7 < np.linalg.norm(g[0]) / np.linalg.norm(fd) < 1.3, (g, fd)
    step = 2e-3 * g / np.linalg.norm(g)
    assert q.losses(xy - step)[0] < q.losses(xy)[0] < q.losses(xy + step)[0]


def test_read_pas_names_the_file(tmp_path):
    from rfmitsuba.eval.locate import read_pas

    with pytest.raises(DatasetError, match="does not exist"):
        read_pas(tmp_path / "none.npy")
    (tmp_path / "junk.npy").write_text("not an array")
    with pytest.raises(DatasetError, match="junk.npy"):
        read_pas(tmp_path / "junk.npy")
    np.save(tmp_path / "one.npy", np.ones((90, 360)))
    assert read_pas(tmp_path / "one.npy").shape == (1, 90, 360)
