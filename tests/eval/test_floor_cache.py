"""rfmitsuba.eval.floor_cache, and evaluate() with it: cached floors equal computed ones."""
import numpy as np
import pytest

from rfmitsuba.eval import dynamic_static
from rfmitsuba.eval import floor_cache as FC


class Counter:
    def __init__(self, arrays):
        self.arrays, self.calls = arrays, 0

    def __call__(self):
        self.calls += 1
        return self.arrays


def test_computed_once_then_read(tmp_path):
    f = Counter({"a": np.arange(4.0), "idx": np.arange(4)})
    key = {"floors": "dynamic", "dataset": "abc"}
    first = FC.cached(tmp_path, key, f, length=4)
    again = FC.cached(tmp_path, key, f, length=4)
    assert f.calls == 1 and set(again) == {"a", "idx"}
    assert np.array_equal(again["a"], first["a"]) and again["idx"].dtype == first["idx"].dtype
    FC.cached(tmp_path, {**key, "dataset": "abd"}, f, length=4)  # another dataset: computed
    FC.cached(None, key, f, length=4)  # no folder: always computed, nothing written
    assert f.calls == 3 and len(list(tmp_path.glob("*.npz"))) == 2


def test_damaged_stale_or_foreign_entries_are_computed_again(tmp_path):
    key = {"floors": "static", "dataset": "abc"}
    f = Counter({"a": np.ones(3)})
    FC.cached(tmp_path, key, f, length=3)
    path = FC.entry_path(tmp_path, key)
    path.write_bytes(path.read_bytes()[:40])  # truncated
    assert np.array_equal(FC.cached(tmp_path, key, f, length=3)["a"], np.ones(3)) and f.calls == 2
    assert FC.load(tmp_path, key, length=3) is not None  # replaced by a whole entry
    assert FC.load(tmp_path, key, length=5) is None  # another test set's length
    other = {"floors": "static", "dataset": "xyz"}
    FC.entry_path(tmp_path, other).write_bytes(path.read_bytes())  # an entry under a foreign name
    assert FC.load(tmp_path, other, length=3) is None


def test_version_is_part_of_the_key(tmp_path, monkeypatch):
    key = {"floors": "dynamic", "dataset": "abc"}
    FC.cached(tmp_path, key, Counter({"a": np.zeros(2)}), length=2)
    monkeypatch.setattr(FC, "FLOORS_VERSION", FC.FLOORS_VERSION + 1)
    assert FC.load(tmp_path, key, length=2) is None


class FakeModel:
    """Renders a fixed smooth image per sample (its antenna index), enough to evaluate."""

    num_primitives = 1

    def render(self, data, idx, *, batch=8, h=90, w=360):
        y, x = np.mgrid[0:h, 0:w]
        a = data.antennas[np.asarray(idx)][:, None, None].astype(np.float32)
        return (np.sin(x / 40.0 + a) * np.cos(y / 25.0 - a)).astype(np.float32)


@pytest.mark.parametrize("noise", [None, 10.0])
def test_evaluate_with_cached_floors_equals_evaluate_without(synthetic_ds, tmp_path, monkeypatch, noise):
    kw = {"noise_snr_db": noise, "noise_seed": 2}
    plain = dynamic_static.evaluate(FakeModel(), synthetic_ds, **kw)
    first = dynamic_static.evaluate(FakeModel(), synthetic_ds, floors_cache=tmp_path, **kw)
    n_entries = len(list(tmp_path.glob("*.npz")))
    assert n_entries == (3 if noise is None else 5)  # 2 parts x (clean [+ noisy]) + the empty room

    def no_floors(*a, **k):
        raise AssertionError("floors computed although cached")

    monkeypatch.setattr(dynamic_static, "floors", no_floors)
    monkeypatch.setattr(dynamic_static, "ssim_images", _only_model_ssim(dynamic_static.ssim_images))
    cached = dynamic_static.evaluate(FakeModel(), synthetic_ds, floors_cache=tmp_path, **kw)
    assert plain["affected"] is not None and plain["dynamic"]["nearest_neighbour"]["n"] > 0
    for ev in (first, cached):
        for part in ("dynamic", "static", "affected"):
            assert ev[part] == plain[part]


def _only_model_ssim(ssim):
    calls = []

    def wrapped(pred, gt):
        calls.append(len(pred))
        if len(calls) > 3:  # the model's two parts and its static fit; the empty room's SSIM is cached
            raise AssertionError("an SSIM of the floors computed although cached")
        return ssim(pred, gt)
    return wrapped
