"""Tests of rfmitsuba.train.frozen_step: a recorded training step equals the traced one."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest


def _cfg(**over):
    from rfmitsuba.core import config as C
    from rfmitsuba.train.config import TrainConfig

    sets = ["model=\"coherent_gaussians\"", "iterations=12", "batch_views=4", "val_every=6", "checkpoint_every=6",
            "log_every=1", "coherent.room_order=2", "coherent.furniture_order=1"]
    return C.override(TrainConfig(), sets + [f"{k}={v}" for k, v in over.items()])


def _losses(run):
    return [json.loads(ln)["loss"] for ln in (run / "log.jsonl").read_text().splitlines()]


def _same(actual, desired, what):
    """Bit for bit on LLVM. On CUDA, within 1e-4 (absolute or relative): CUDA sums gradients with
    atomics in no fixed order, so a traced run differs from itself there too (docs/limits.md,
    run-to-run spread), and Adam turns a rounding-level difference of a near-zero gradient into up to a
    learning rate (1e-2) per step. Measured on an H100 (2026-11-27, 8 to 12 steps): losses within
    5e-8, parameters within 2.7e-5."""
    from rfmitsuba.core import backend as B

    kind = np.asarray(desired).dtype.kind
    if B.is_cuda() and kind == "f":
        np.testing.assert_allclose(actual, desired, rtol=1e-4, atol=1e-4, err_msg=what)
    elif B.is_cuda() and kind == "U" and np.ndim(desired) == 0:   # a field's JSON meta: its floats too
        a, d = json.loads(str(actual)), json.loads(str(desired))
        assert a.keys() == d.keys(), what
        for k in d:
            if isinstance(d[k], float):
                np.testing.assert_allclose(a[k], d[k], rtol=1e-4, atol=1e-4, err_msg=f"{what}: {k}")
            else:
                assert a[k] == d[k], f"{what}: {k}"
    else:   # names and counts stay exact
        np.testing.assert_array_equal(actual, desired, err_msg=what)


@pytest.fixture(scope="module")
def quick_data(quick_dataset):
    from rfmitsuba.data.views import TrainData

    return TrainData.open(quick_dataset.path)


def test_a_recorded_run_is_bit_identical_to_a_traced_one(quick_data, tmp_path, one_thread):
    """12 steps of the coherent Gaussian field with and without recording: the same loss at every
    step and the same trained parameters to the last bit; the recorded run replayed most steps."""
    from rfmitsuba.train.trainer import Trainer

    traced = Trainer(_cfg(), quick_data, tmp_path / "traced", quiet=True, freeze=False)
    traced.run()
    rec = Trainer(_cfg(), quick_data, tmp_path / "recorded", quiet=True)
    rec.run()
    assert traced._frozen_loss is None
    assert 1 <= rec._frozen_loss.recordings < 12 and not rec._frozen_loss.disabled
    _same(_losses(tmp_path / "recorded"), _losses(tmp_path / "traced"), "losses")
    with np.load(tmp_path / "traced" / "final" / "field.npz") as a, \
            np.load(tmp_path / "recorded" / "final" / "field.npz") as b:
        assert sorted(a.files) == sorted(b.files)
        for k in a.files:
            _same(b[k], a[k], k)


def test_a_field_without_scatterers_is_recorded(quick_data, tmp_path, one_thread, recwarn):
    """No scatterers: the field's scatterer arrays are empty, which a recording cannot take (Dr.Jit
    aborts the process); they are left out of the inputs and the run records and replays as usual."""
    from rfmitsuba.train.trainer import Trainer

    cfg = _cfg(iterations=6, **{"coherent_gaussians.scatterers": 0, "coherent_gaussians.room_scatterers": 0})
    tr = Trainer(cfg, quick_data, tmp_path / "run", quiet=True)
    tr.run()
    assert tr.field.num_scatterers == 0
    assert 1 <= tr._frozen_loss.recordings < 6 and not tr._frozen_loss.disabled
    assert not [w for w in recwarn if "cannot be recorded" in str(w.message)]


@pytest.fixture(scope="module")
def trained(quick_data, tmp_path_factory):
    """A coherent Gaussian field after 6 traced steps, and the trainer that made it."""
    from rfmitsuba.train.trainer import Trainer

    tr = Trainer(_cfg(iterations=6), quick_data, tmp_path_factory.mktemp("frozen") / "run", quiet=True, freeze=False)
    tr.run()
    return tr


def _loss_and_grads(frozen, field, views, gt):
    """The loss of ``views`` (recorded by ``frozen``, or traced where it is None) and the gradient
    of every parameter, as NumPy; gradients cleared first and after."""
    import drjit as dr

    from rfmitsuba.train.loss import loss as loss_fn

    params = {k: dr.detach(v) for k, v in field.params.items()}
    for v in params.values():
        dr.enable_grad(v)
    field.params.update(params)
    if frozen is None:
        from rfmitsuba.train.frozen_step import _loss

        loss = _loss([field], [field.prepare(views)], gt, loss_fn, frequency_hz=views.frequency_hz,
                     height=gt.shape[1], width=gt.shape[2])
    else:
        loss = frozen([field], views, gt, loss_fn)
    grads = {k: np.array(dr.grad(v).numpy()) for k, v in params.items()}
    field.params.update({k: dr.detach(v) for k, v in params.items()})
    return float(loss.numpy()[0]), grads


def test_a_new_batch_size_is_recorded_anew_and_replays_match_tracing(trained, quick_data, one_thread):
    """Batches of 4, 4, 2 and 4 views: the 2-view batch makes a new recording (its inputs are
    narrower), the second 4-view batch replays the first's; every loss and gradient equals the
    traced step's."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.base import Views
    from rfmitsuba.train.frozen_step import FrozenLoss

    field = trained.field
    frozen = FrozenLoss(height=trained.h, width=trained.w)
    fit = np.arange(len(quick_data.antenna_pos))
    counts = []
    for rows in (fit[:4], fit[4:8], fit[8:10], fit[10:14]):
        views = Views.of(quick_data, rows)
        gt = B.TensorXf(quick_data.pas(rows, d=trained.d))
        lf, gf = _loss_and_grads(frozen, field, views, gt)
        lt, gt_ = _loss_and_grads(None, field, views, gt)
        _same(lf, lt, "loss")
        for k in gf:
            _same(gf[k], gt_[k], k)
        counts.append(frozen.recordings)
    assert counts[1] == counts[0] and counts[2] == counts[1] + 1 and counts[3] == counts[2], counts


def test_a_step_whose_recording_fails_is_traced_with_a_warning(trained, quick_data, monkeypatch, one_thread):
    """A recording that raises (here the field's device part, the first time, which is inside the
    recording) is given up: the step says so once, naming the field, and is traced from then on,
    with the traced step's loss."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.base import Views
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianField
    from rfmitsuba.train.frozen_step import FrozenLoss

    real, calls = CoherentGaussianField.channels_prepared, []

    def failing_once(self, prep):
        calls.append(1)
        if len(calls) == 1:
            raise RuntimeError("cannot record this")
        return real(self, prep)

    monkeypatch.setattr(CoherentGaussianField, "channels_prepared", failing_once)
    field = trained.field
    frozen = FrozenLoss(height=trained.h, width=trained.w)
    rows = np.arange(4)
    views = Views.of(quick_data, rows)
    gt = B.TensorXf(quick_data.pas(rows, d=trained.d))
    with pytest.warns(RuntimeWarning, match="CoherentGaussianField: its training step cannot be recorded"):
        lf, _ = _loss_and_grads(frozen, field, views, gt)
    assert frozen.disabled
    lt, _ = _loss_and_grads(None, field, views, gt)
    assert lf == lt and len(calls) == 3


def test_no_garbage_collection_inside_a_step(trained, quick_data, monkeypatch, one_thread):
    """Python's cyclic garbage collector is off while a step is recorded or replayed (a collection
    during a recording once aborted the process) and on again after, also when the recording fails."""
    import gc

    from rfmitsuba.core import backend as B
    from rfmitsuba.models.base import Views
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianField
    from rfmitsuba.train.frozen_step import FrozenLoss

    real, seen = CoherentGaussianField.channels_prepared, []

    def watched(self, prep):
        seen.append(gc.isenabled())
        if len(seen) == 2:
            raise RuntimeError("cannot record this")
        return real(self, prep)

    monkeypatch.setattr(CoherentGaussianField, "channels_prepared", watched)
    frozen = FrozenLoss(height=trained.h, width=trained.w)
    rows = np.arange(4)
    gt = B.TensorXf(quick_data.pas(rows, d=trained.d))
    assert gc.isenabled()
    _loss_and_grads(frozen, trained.field, Views.of(quick_data, rows), gt)        # recorded
    assert gc.isenabled()
    with pytest.warns(RuntimeWarning, match="cannot be recorded"):                 # a new shape fails
        _loss_and_grads(frozen, trained.field, Views.of(quick_data, np.arange(6)),
                        B.TensorXf(quick_data.pas(np.arange(6), d=trained.d)))
    assert gc.isenabled() and seen[:2] == [False, False]


def _equal_jobs(method, quick_dataset, tmp_path, monkeypatch):
    """Method ``method`` of the coherent Gaussian family trained twice (recorded, then traced with
    recording switched off): the same losses at every logged step and the same fields, bit for bit
    (on LLVM; see :func:`_same`)."""
    from rfmitsuba.core import config as C
    from rfmitsuba.experiments import methods
    from rfmitsuba.train.frozen_step import FrozenLoss

    s1 = C.override(_cfg(iterations=8, val_every=8, checkpoint_every=8), ["log_every=1"])
    mc = methods.MethodConfig(stage1=s1, stage2_iterations=8)
    real, kinds = FrozenLoss.__call__, []

    def counted(self, fields, *args):
        loss = real(self, fields, *args)
        kinds.append((tuple(type(f).__name__ for f in fields), self.disabled))
        return loss

    monkeypatch.setattr(FrozenLoss, "__call__", counted)
    runs = {}
    for name in ("recorded", "traced"):
        if name == "traced":
            monkeypatch.setattr(FrozenLoss, "supports", staticmethod(lambda fields: False))
        r = methods.train_method(method, quick_dataset.path, tmp_path / name, mcfg=mc, seed=0)
        runs[name] = [Path(p) for p in r["runs"]]
    # every step of the recorded job went through a recording: Ours' 8 Stage-1 steps, then its 8 Stage-2
    # steps with the frozen background; End-to-End's 16 steps of the joint field
    want = ([("CoherentGaussianField",)] * 8 + [("CoherentGaussianField", "CoherentGaussianPersonField")] * 8
            if method == "ours" else [("CoherentGaussianJointField",)] * 16)
    assert [k for k, _ in kinds] == want and not any(disabled for _, disabled in kinds)
    for a, b in zip(runs["recorded"], runs["traced"]):
        _same(_losses(a), _losses(b), f"{a.name}: losses")
        with np.load(a / "final" / "field.npz") as za, np.load(b / "final" / "field.npz") as zb:
            for k in za.files:
                _same(za[k], zb[k], f"{a.name}: {k}")


@pytest.mark.parametrize("method", ["ours", "end_to_end"])
def test_stage2_and_the_joint_field_record_bit_identically(method, quick_dataset, tmp_path, monkeypatch,
                                                           one_thread):
    """Ours' Stage 2 (a frozen background and the person field rendered together) and End-to-End's
    joint field (batches with and without a person present) record and replay as traced."""
    _equal_jobs(method, quick_dataset, tmp_path, monkeypatch)
