"""rfmitsuba.eval.anchor: the neighbour-anchored prediction on hand-made spectra whose answers are
known (alpha = 0 is IDW; a perfect field's changes give the truth back; a useless field is not
chosen)."""
from __future__ import annotations

import numpy as np
import pytest

from rfmitsuba.eval import anchor
from rfmitsuba.eval.metrics import idw_predict


def _scene(n=40, seed=0):
    """Spectra that move with position: a bump whose column follows x, on 18 x 72 images."""
    rng = np.random.default_rng(seed)
    pos = np.column_stack([np.sort(rng.uniform(0, 1, n)), rng.uniform(0, 0.2, n), np.zeros(n)])
    cols = np.arange(72)
    pas = np.exp(-0.5 * ((cols[None, None, :] - (10 + 50 * pos[:, :1, None])) / 4.0) ** 2) * np.ones((1, 18, 1))
    pas = pas + 0.3 * np.linspace(0, 1, 18)[None, :, None]
    lo, hi = pas.min(axis=(1, 2), keepdims=True), pas.max(axis=(1, 2), keepdims=True)
    return pos, ((pas - lo) / (hi - lo)).astype(np.float32)


def test_alpha_zero_is_idw_and_a_perfect_field_gives_the_truth():
    pos, pas = _scene()
    pool, query = np.arange(0, 40, 2), np.arange(1, 40, 2)
    idw = anchor.anchored(pas[query], pas[pool], pas[pool], pos[pool], pos[query], k=3, alpha=0.0)
    assert np.abs(idw - idw_predict(pas[pool], pos[pool], pos[query], k=3)).max() < 1e-5
    perfect = anchor.anchored(pas[query], pas[pool], pas[pool], pos[pool], pos[query], k=3, alpha=1.0)
    assert np.abs(perfect - pas[query]).max() < 1e-5


def test_choose_prefers_a_good_field_and_refuses_a_useless_one():
    pos, pas = _scene()
    fit, val = np.arange(0, 32), np.arange(32, 40)           # validation: the outer slab of x
    good = anchor.choose(pas[val], pas[fit], pas[fit], pos[fit], pos[val], pas[val])
    assert good["val_ssim"] > 0.999 and (good["use"] == "field" or good["alpha"] == 1.0)
    noise = np.random.default_rng(1).random(pas.shape).astype(np.float32)
    bad = anchor.choose(noise[val], noise[fit], pas[fit], pos[fit], pos[val], pas[val])
    assert bad["use"] == "anchored" and bad["alpha"] == 0.0
    assert bad["field_val_ssim"] < bad["val_ssim"]
    assert len(bad["grid"]) == len(anchor.KS) * len(anchor.ALPHAS)


def test_bad_input_is_named():
    pos, pas = _scene()
    with pytest.raises(ValueError, match="k >= 1"):
        anchor.anchored(pas[:2], pas, pas, pos, pos[:2], k=0, alpha=0.5)
    with pytest.raises(ValueError, match="shapes differ"):
        anchor.anchored(pas[:2], pas[:5], pas, pos, pos[:2], k=1, alpha=0.5)
