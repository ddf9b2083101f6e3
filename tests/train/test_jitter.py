"""Tests of rfmitsuba.train.jitter: jittered copies of a training batch."""
from __future__ import annotations

import json

import numpy as np
import pytest


def _views(task, count=4000, extra=False):
    from rfmitsuba.models.base import Views

    rng = np.random.default_rng(0)
    q = rng.uniform(0, 3, (count, 3))
    fixed = np.tile([5.0, 1.0, 2.0], (count, 1))
    x, y = (q, fixed) if task == "rx" else (fixed, q)
    inputs = (lambda field: np.arange(count, dtype=np.float32)[:, None]) if extra else (lambda field: None)
    return Views(antenna_pos=q, view_pos=x, transmitter=y, rx_to_world=None, frequency_hz=920e6, task=task,
                 inputs=inputs)


@pytest.mark.parametrize("task", ["rx", "tx"])
def test_jittered_copies_move_the_moving_device_by_the_spread(task):
    """(1 + copies) B views: the batch itself first, then each copy with the moving device (the
    array with the receiver in the RX task, the transmitter in the TX task) displaced by N(0,
    (spread lambda)^2) per axis, the fixed device unmoved, the targets repeated in the same order."""
    from rfmitsuba.rf import array as antenna
    from rfmitsuba.train.jitter import jittered

    v = _views(task)
    gt = np.random.default_rng(1).random((v.count, 2, 3)).astype(np.float32)
    out, gt_out = jittered(v, gt, spread=0.15, copies=2, rng=np.random.default_rng(2))
    B = v.count
    assert out.count == 3 * B and gt_out.shape == (3 * B, 2, 3)
    np.testing.assert_array_equal(gt_out, np.concatenate([gt, gt, gt]))
    np.testing.assert_array_equal(out.antenna_pos[:B], v.antenna_pos)
    d = (out.antenna_pos[B:] - np.tile(v.antenna_pos, (2, 1)))
    sigma = 0.15 * antenna.wavelength(920e6)
    np.testing.assert_allclose(d.std(axis=0), sigma, rtol=0.05)
    np.testing.assert_allclose(d.mean(axis=0), 0.0, atol=4 * sigma / np.sqrt(2 * B))
    moving, fixed = (out.view_pos, out.transmitter) if task == "rx" else (out.transmitter, out.view_pos)
    np.testing.assert_array_equal(moving, out.antenna_pos)
    np.testing.assert_array_equal(fixed, np.tile(fixed[:1], (3 * B, 1)))
    assert (out.task, out.frequency_hz, out.rx_to_world) == (task, 920e6, None)


def test_copies_keep_their_views_extra_inputs():
    """A field with extra inputs (Stage 2: the person) gets each copy's own view's inputs."""
    from rfmitsuba.train.jitter import jittered

    class F:
        extra_inputs = 1

    v = _views("rx", count=5, extra=True)
    out, _ = jittered(v, np.zeros((5, 1, 1), np.float32), spread=0.1, copies=1, rng=np.random.default_rng(0))
    np.testing.assert_array_equal(out.extra(F()).ravel(), np.concatenate([np.arange(5), np.arange(5)]))


def test_bad_spread_copies_and_mixed_views_are_refused():
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.base import Views
    from rfmitsuba.train.config import TrainConfig
    from rfmitsuba.train.jitter import jittered

    v = _views("tx", count=3)
    gt = np.zeros((3, 1, 1), np.float32)
    for spread, copies in ((0.0, 1), (float("nan"), 1), (-1.0, 1), (0.1, 0)):
        with pytest.raises(ConfigError, match="spread > 0 wavelengths and copies >= 1"):
            jittered(v, gt, spread=spread, copies=copies, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="differ in task"):
        Views.concat([v, _views("rx", count=3)])
    framed = Views.concat([v, v]).moved(np.zeros((6, 3)))
    framed.rx_to_world = np.eye(3)
    with pytest.raises(ValueError, match="array frame"):
        Views.concat([v, framed])
    assert Views.concat([framed, framed]).count == 12
    for bad in (-0.5, float("inf")):
        with pytest.raises(ConfigError, match="TrainConfig.jitter must be 'auto'"):
            TrainConfig(jitter=bad)


def test_a_jittered_run_records_and_trains_on_the_copies(quick_dataset, tmp_path, one_thread):
    """12 steps of the coherent Gaussian field with jittered copies: the recorded run replays and
    agrees with the traced one bit for bit on LLVM (the copies are a batch like any other), and
    the losses differ from a run without copies from the first step on."""
    from rfmitsuba.core import config as C
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.config import TrainConfig
    from rfmitsuba.train.trainer import Trainer

    data = TrainData.open(quick_dataset.path)
    sets = ["model=\"coherent_gaussians\"", "iterations=12", "batch_views=4", "val_every=6", "checkpoint_every=6",
            "log_every=1"]

    def losses(name, jitter, **kw):
        t = Trainer(C.override(TrainConfig(), sets + [f"jitter={jitter}"]), data, tmp_path / name, quiet=True, **kw)
        t.run()
        assert t.jitter == jitter
        return t, [json.loads(ln)["loss"] for ln in (tmp_path / name / "log.jsonl").read_text().splitlines()]

    (t_rec, rec), (t_traced, traced) = losses("rec", 0.2), losses("traced", 0.2, freeze=False)
    assert 1 <= t_rec._frozen_loss.recordings < 12 and not t_rec._frozen_loss.disabled   # it did replay
    assert t_traced._frozen_loss is None
    from rfmitsuba.core import backend as B

    if B.is_cuda():    # CUDA's atomic sums run in no fixed order (tests/train/test_frozen_step.py)
        np.testing.assert_allclose(rec, traced, rtol=1e-4, atol=1e-4)
    else:
        np.testing.assert_array_equal(rec, traced)
    _, plain = losses("plain", 0.0)
    assert len(plain) == len(rec) and rec[0] != plain[0]
