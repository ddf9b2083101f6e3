"""A training batch's render, loss and backward pass recorded once and replayed (``dr.freeze``).

A small field's training step spends much of its time tracing: the coherent Gaussian field's
Stage-1 step (73 sources, batch 8, 45 x 180) spends about 18 ms in kernels and about 12 ms
building and generating them again every step (one Dr.Jit thread; docs/lab-notes/speed.md). :class:`FrozenLoss` traces the device part of a step once per *structure* and then replays
its kernels with the new batch: the same kernels on the same inputs, so the losses and
parameters are bit-identical to the traced step's (``tests/train/test_frozen_step.py``).

The fields of a step (frozen ones first, the trained one last, one family) take part when each
class has ``freezable = True`` and these methods (the coherent Gaussian family:
:class:`~rfmitsuba.models.coherent_gaussians.CoherentGaussianField`, its Stage-2 person field and
the joint field of End-to-End and Stage 3):

===============================================  ===============================================
``prepare(views) -> prep``                       the host part of the field's channels (checks,
                                                 cached ray casts, uploads), run every step
``channels_prepared(prep) -> (re, im)``          the device part: its channels at the elements
``device_inputs(prep) -> list``                  every Dr.Jit array the device part reads
``structure(prep) -> tuple``                     what it takes from Python (counts, flags)
``read_out_channels(re, im, *, frequency_hz,     the family's read-out of the summed channels
height, width)`` (first field)                   (``TensorXf`` [B, H, W])
``read_out_inputs(*, frequency_hz, height,       the Dr.Jit arrays the read-out reads
width)`` (first field)
``penalty()`` (trained field)                    as every field
===============================================  ===============================================

A new recording is made whenever the structure, the width of any input or the loss function
changes (a plane pursuit adding sources, another batch size), so a replay never runs kernels
traced for other sizes. If a recording raises, the step is traced as usual from then on, with a
warning naming the field. An array the device part reads but ``device_inputs`` leaves out is an
error Dr.Jit may not survive (it aborts the process where a symbolic loop reads it), so
``device_inputs`` must be complete: ``tests/train/test_frozen_step.py`` checks recorded runs
against traced ones bit for bit.

Dr.Jit borrows the memory of a NumPy array it is given, and whether that memory is 64-byte
aligned is part of what a recording is valid for. NumPy gives no such promise, so the batch's
uploads (``prep``'s arrays and the target images) are copied into aligned buffers first
(:func:`rfmitsuba.core.upload.aligned`; LLVM only): without that, a 1500-step run recorded 9 times; with it, a
3000-step run twice.
"""
from __future__ import annotations

import gc

import warnings

import numpy as np

from ..core import backend as B
from ..core.upload import aligned


def _realigned(tree):
    """``tree`` (dicts, lists, tuples) with every Dr.Jit array replaced by one of the same type
    on an :func:`aligned` copy of its values; anything else kept."""
    import drjit as dr

    if dr.is_array_v(tree):
        return type(tree)(aligned(np.asarray(tree.numpy())))
    if isinstance(tree, dict):
        return {k: _realigned(v) for k, v in tree.items()}
    if isinstance(tree, (list, tuple)):
        return type(tree)(_realigned(v) for v in tree)
    return tree


class _Hold:
    """What the recorded function reads from Python: an object Dr.Jit leaves opaque (compared
    by identity), so changing its attributes never causes a new recording."""

    fields: list = []
    preps: list = []
    loss_fn = None
    frequency_hz = 0.0
    key: tuple = ()


def _loss(fields: list, preps: list, gt, loss_fn, *, frequency_hz: float, height: int, width: int):
    """The batch's loss from the fields' prepared parts, back-propagated: the channels summed, read
    out once, ``loss_fn`` plus the trained field's penalty (``Float`` [1])."""
    import drjit as dr

    hr = hi = None
    for f, prep in zip(fields, preps):
        fr, fi = f.channels_prepared(prep)
        hr, hi = (fr, fi) if hr is None else (hr + fr, hi + fi)
    pred = fields[0].read_out_channels(hr, hi, frequency_hz=frequency_hz, height=height, width=width)
    loss = loss_fn(pred, gt)
    penalty = fields[-1].penalty()
    if penalty is not None:
        loss = loss + penalty
    dr.backward(loss)
    return loss


class FrozenLoss:
    """The loss of one batch with its backward pass, recorded by ``dr.freeze`` and replayed.

    Args:
        height, width: the training images [pixels].
        limit: recordings kept (least recently used dropped).

    Calling it with ``(fields, views, gt, loss_fn)`` (``fields`` rendered together: the frozen
    ones, then the trained one) runs each field's ``prepare(views)`` on the host, then (recorded
    once per structure, replayed after) sums their channels, reads them out, takes
    ``loss_fn(pred, gt)`` plus the trained field's ``penalty()`` and back-propagates it into the
    parameters; it returns the loss (``Float`` [1]). ``gt`` is a ``TensorXf`` [B, height, width].
    """

    def __init__(self, *, height: int, width: int, limit: int = 8):
        import drjit as dr

        self.height, self.width = int(height), int(width)
        self.disabled = False
        hold = self._hold = _Hold()

        def step(inputs, gt):
            return _loss(hold.fields, hold.preps, gt, hold.loss_fn, frequency_hz=hold.frequency_hz, height=height,
                         width=width)

        self._frozen = dr.freeze(step, state_fn=lambda inputs, gt: hold.key, limit=limit)

    @staticmethod
    def supports(fields: list) -> bool:
        """Whether ``fields`` can take part: every class says ``freezable``, one family, and
        Dr.Jit has ``freeze``."""
        import drjit as dr

        return (bool(fields) and all(getattr(type(f), "freezable", False) for f in fields)
                and len({f.family for f in fields}) == 1 and hasattr(dr, "freeze"))

    @property
    def recordings(self) -> int:
        """Recordings made so far (each a traced step; every other call was a replay)."""
        return int(self._frozen.n_recordings)

    def __call__(self, fields: list, views, gt, loss_fn):
        import drjit as dr

        fields = list(fields)
        preps = [f.prepare(views) for f in fields]
        size = {"frequency_hz": float(views.frequency_hz), "height": self.height, "width": self.width}
        if self.disabled:
            return _loss(fields, preps, gt, loss_fn, **size)
        if not B.is_cuda():   # a CUDA upload is a copy into the device's own memory
            preps, gt = _realigned(preps), _realigned(gt)
        h = self._hold
        h.fields, h.preps, h.loss_fn, h.frequency_hz = fields, preps, loss_fn, size["frequency_hz"]
        # an empty array (a field without scatterers) is read by no kernel, and Dr.Jit's recording
        # aborts the process on one: it is left out
        arrays = [a for f, prep in zip(fields, preps) for a in f.device_inputs(prep)]
        arrays += fields[0].read_out_inputs(**size)
        inputs = [a for a in arrays if dr.width(a) > 0]
        h.key = (tuple(f.structure(prep) for f, prep in zip(fields, preps)), tuple(dr.width(a) for a in inputs),
                 id(loss_fn), size["frequency_hz"])
        # no cyclic garbage collection inside the call: a collection that freed Dr.Jit arrays
        # while a step was being recorded aborted the process once (tests/cli/test_cli_demo.py,
        # 2026-11-28; "Fatal Python error: Aborted ... Garbage-collecting" in the person field's
        # _lanes); reference counting still frees everything else at once
        collecting = gc.isenabled()
        gc.disable()
        try:
            return self._frozen(inputs, gt)
        except RuntimeError as e:   # a recording that failed: trace every step from now on
            self.disabled = True
            warnings.warn(f"{type(fields[-1]).__name__}: its training step cannot be recorded ({e}); "
                          "tracing it every step instead", RuntimeWarning, stacklevel=2)
            return _loss(fields, preps, gt, loss_fn, **size)
        finally:
            if collecting:
                gc.enable()
