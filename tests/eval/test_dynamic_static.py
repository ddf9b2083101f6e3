"""Tests of rfmitsuba.eval.dynamic_static: the parts of evaluate() beyond the floors (those are
in test_floor_cache.py): the static fit at training positions and the breakdown by distance."""
import numpy as np

from rfmitsuba.data.samples import SampleData
from rfmitsuba.eval import dynamic_static as DS


class OracleAtTestPositions:
    """The true PAS at test positions and a constant image at training ones: test SSIM 1, fit low."""

    num_primitives = 1

    def __init__(self, data):
        sets = DS.test_sets(data)
        self.test = np.concatenate([sets["static_test"], sets["dynamic_test"]])

    def render(self, data, idx, *, batch=8):
        idx = np.asarray(idx)
        out = data.pas(idx).astype(np.float32)
        flat = np.zeros_like(out)
        flat[:, :, :180] = 1.0
        return np.where(np.isin(idx, self.test)[:, None, None], out, flat)


def test_fit_and_breakdown(synthetic_ds):
    data = SampleData.open_samples(synthetic_ds, states="all")
    ev = DS.evaluate(OracleAtTestPositions(data), synthetic_ds)
    st = ev["static"]
    assert st["model"]["mean"] > 0.999
    n_train = len(DS.test_sets(data)["static_train"])
    assert st["fit"]["n"] == min(DS.FIT_POSITIONS, n_train)
    assert st["fit"]["mean"] < 0.5          # the oracle knows nothing at training positions
    assert "fit" not in ev["dynamic"]
    for part in ("static", "dynamic"):
        b = ev[part]["by_distance"]
        for dist in ("to_fixed_device", "to_nearest_training"):
            assert sum(b[dist]["count"]) == ev[part]["test_samples"]
            assert np.allclose(b[dist]["model"], 1.0, atol=1e-3)
            w = np.asarray(b[dist]["count"])
            assert np.isclose(np.average(b[dist]["nearest_neighbour"], weights=w),
                              ev[part]["nearest_neighbour"]["mean"])
