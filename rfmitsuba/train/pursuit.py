"""Coherent plane pursuit: an unknown room's field grows the planes its loss asks for.

The data scan (:func:`rfmitsuba.models.coherent_gaussians.scan`) finds reflecting planes by
arrival direction. It cannot find a wall next to the fixed device: that wall's image arrives
within the array's beam of the direct path, and the beam around the direct path is explained
first. Such a wall shows only coherently, as fringes between the direct path and its image as
the moving device moves.

:class:`PlanePursuit` finds it by matching pursuit on the loss itself. At each fraction
``pursuit_at`` of the run (:class:`~rfmitsuba.models.coherent_gaussians.CoherentGaussianConfig`)
it

1. takes ``G``, the gradient of the training loss with respect to the field's calibrated channels
   at ``pursuit_views`` training views (evenly spaced), through the same read-out as training;
2. scores every candidate plane ``coord_a = d`` (:func:`plane_candidates`: the three axes, every
   ``step`` metres beyond the known positions' span, up to ``margin``) by the gradient of the
   loss with respect to the complex gain of the transmitter's image across it, at zero gain
   (:meth:`~rfmitsuba.models.coherent_gaussians.CoherentGaussianField.image_gain_gradients`):
   the loss's rate of change per unit of the image's gain. The gain is a reflection
   coefficient (the spreading 1/L is in the channel), of order 1 for a wall at any distance, so
   the score is not divided by the candidate channel's norm: that would favour far images,
   which need gains far above 1 to matter (on a planted wall 0.3 m from the transmitter the
   divided score ranked a plane 3.4 m below the floor first; this score ranks the wall first);
3. keeps the ``pursuit_planes`` best (:func:`pick_planes`: no two on one axis closer than
   ``min_separation``, none closer than ``existing_separation`` to a plane the field has) and adds their images with zero
   gain: the single reflections, and when ``image_order`` >= 2 the double reflections across
   each new plane and each of the field's planes (both orders). Adam's moments of the old
   parameters move with them; the new ones start at zero.

The hooks follow :class:`rfmitsuba.train.density.Strategy`; a resumed run does not repeat a
pursuit (its steps are in the checkpoint, the field's grown geometry too).
"""
from __future__ import annotations

import numpy as np

from ..core import backend as B
from ..models.base import Views
from ..models.coherent_gaussians import CoherentGaussianField, read_out, summed_channels, uses_pursuit
from .density import Strategy, move_adam_state

#: candidate planes' spacing [m], how far beyond the known positions they reach [m], and the
#: closest two planes picked in one pursuit may be on one axis [m]
PLANE_STEP, PLANE_MARGIN, MIN_SEPARATION = 0.05, 4.0, 0.3
#: the closest a picked plane may be to one the field has on the same axis [m]: more than one
#: candidate step, so a plane the scan or an earlier pursuit put 10-20 cm off a wall does not
#: hide the wall (blind bedroom, moving TX, seed 0: 0.831 with 0.3 m here, 0.869 with 0.08 m)
EXISTING_SEPARATION = 0.08
#: views per gradient batch
CHUNK = 16


def plane_candidates(positions: np.ndarray, *, step: float = PLANE_STEP,
                     margin: float = PLANE_MARGIN) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned candidate planes beyond every known position.

    Args:
        positions: float [N, 3] array centres, transmitters and moving devices [m].
        step: offset spacing [m]; margin: how far beyond the positions' span [m].
    Returns:
        (axis int64 [C], offset float64 [C] [m]) with offsets below the positions' minimum or
        above their maximum along that axis (a wall does not cut through the devices).
    """
    pts = np.asarray(positions, np.float64).reshape(-1, 3)
    lo, hi = pts.min(0), pts.max(0)
    axis, off = [], []
    for a in range(3):
        below = lo[a] - np.arange(1, int(np.floor(margin / step)) + 1) * step
        above = hi[a] + np.arange(1, int(np.floor(margin / step)) + 1) * step
        d = np.concatenate([below[::-1], above])
        axis.append(np.full(len(d), a, np.int64))
        off.append(d)
    return np.concatenate(axis), np.concatenate(off)


def reflection(axis: int, offset: float) -> tuple[np.ndarray, np.ndarray]:
    """The reflection ``y -> A y + b`` across the plane ``coord_axis = offset`` [m]."""
    A = np.eye(3)
    A[axis, axis] = -1.0
    b = np.zeros(3)
    b[axis] = 2.0 * offset
    return A, b


def pick_planes(score: np.ndarray, axis: np.ndarray, offset: np.ndarray, *, count: int,
                existing_axis: np.ndarray, existing_offset: np.ndarray,
                min_separation: float = MIN_SEPARATION,
                existing_separation: float = EXISTING_SEPARATION) -> list[int]:
    """The ``count`` best-scoring candidates, greedily: none within ``min_separation`` [m] of
    another kept one, nor within ``existing_separation`` [m] of a plane the field has, on the
    same axis. A field's plane may sit a few centimetres to decimetres off the wall it draws, so
    a candidate near it may still be the wall itself. Returns indices into the candidates."""
    keep: list[int] = []
    ex = list(zip(np.asarray(existing_axis).tolist(), np.asarray(existing_offset, np.float64).tolist()))
    for i in np.argsort(-np.asarray(score), kind="stable"):
        if len(keep) >= count:
            break
        if not np.isfinite(score[i]) or score[i] <= 0:
            break
        if any(a == axis[i] and abs(o - offset[i]) < existing_separation for a, o in ex) or \
                any(axis[j] == axis[i] and abs(offset[j] - offset[i]) < min_separation for j in keep):
            continue
        keep.append(int(i))
    return keep


def new_images(field: CoherentGaussianField, planes: list[tuple[int, float]], *,
               max_order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Images of new ``planes`` ((axis, offset [m]) pairs): each single reflection and, for
    ``max_order`` >= 2, the double reflections across a new plane and any other plane (the
    field's single planes where they are now, and the other new ones), both orders.

    Returns:
        (A float64 [n, 3, 3], b float64 [n, 3] [m], order int64 [n]).
    """
    singles = [reflection(a, o) for a, o in planes]
    A, b, order = [m[0] for m in singles], [m[1] for m in singles], [1] * len(singles)
    if max_order >= 2:
        ex_axis, ex_off = field.single_planes()
        others = [reflection(a, o) for a, o in zip(ex_axis, ex_off)] + singles
        for n, (An, bn) in enumerate(singles):
            for j, (Aj, bj) in enumerate(others):
                if j == len(others) - len(singles) + n:      # itself
                    continue
                for (A1, b1), (A2, b2) in (((Aj, bj), (An, bn)), ((An, bn), (Aj, bj))):
                    A.append(A2 @ A1)                         # across plane 1, then plane 2
                    b.append(A2 @ b1 + b2)
                    order.append(2)
    A, b, order = np.stack(A), np.stack(b), np.asarray(order, np.int64)
    key = np.round(np.concatenate([A.reshape(-1, 9), b], 1), 6)
    _, first = np.unique(key, axis=0, return_index=True)
    first = np.sort(first)
    return A[first], b[first], order[first]


class PlanePursuit(Strategy):
    """Adds planes to an unknown room's :class:`CoherentGaussianField` during training (module
    docstring).

    Args:
        data: the run's :class:`~rfmitsuba.data.views.TrainData`; fit: int [F] its training indices.
        frozen: fields rendered with the trained one (their channels add).
        downsample: the training PAS's downsampling (the loss's resolution).
        prefix: the field's key prefix in the optimizer.
        iterations: the run's length (the pursuit steps are fractions of it).
    """

    def __init__(self, *, data, fit: np.ndarray, frozen: list, downsample: int, prefix: str, iterations: int,
                 planes: int, at: tuple[float, ...], views: int, loss_fn):
        super().__init__()
        self.data, self.frozen, self.d, self.prefix = data, list(frozen), int(downsample), prefix
        self.planes, self.loss_fn = int(planes), loss_fn
        fit = np.asarray(fit, np.int64)
        self.idx = fit[np.unique(np.linspace(0, len(fit) - 1, min(len(fit), views)).round().astype(np.int64))]
        self.steps = sorted({min(max(1, int(round(t * iterations))), iterations - 1) for t in at})
        self.done: list[int] = []

    def step_end(self, step: int, field, opt, *, rng=None, probe_views=None) -> bool:
        if step not in self.steps or step in self.done:
            return False
        self.done.append(step)
        event = self.pursue(field, opt)
        event["step"] = step
        self.history.append(event)
        return bool(event["images_added"])

    def loss_gradient(self, field) -> tuple[np.ndarray, np.ndarray]:
        """The training loss's gradient at the summed calibrated channels of the frozen and
        trained fields, at the pursuit's training positions ``self.idx``: (re, im) float64 [B*16]."""
        import drjit as dr

        h, w = 90 // self.d, 360 // self.d
        gr, gi = [], []
        for i in range(0, len(self.idx), CHUNK):
            idx = self.idx[i:i + CHUNK]
            v = Views.of(self.data, idx)
            with dr.suspend_grad():
                hr, hi = summed_channels(self.frozen + [field], v)
            hr, hi = B.Float(np.asarray(hr.numpy())), B.Float(np.asarray(hi.numpy()))
            dr.enable_grad(hr, hi)
            pred = read_out(hr, hi, readout=field.readout, frequency_hz=v.frequency_hz, height=h, width=w,
                            normalize=True)
            loss = self.loss_fn(pred, B.TensorXf(self.data.pas(idx, d=self.d)))
            dr.backward(loss)
            gr.append(np.asarray(dr.grad(hr).numpy(), np.float64))
            gi.append(np.asarray(dr.grad(hi).numpy(), np.float64))
        return np.concatenate(gr), np.concatenate(gi)

    def pursue(self, field: CoherentGaussianField, opt) -> dict:
        """One pursuit: score, pick and add planes; remap the optimizer. Returns the event."""
        gr, gi = self.loss_gradient(field)
        tr_x, tr_y, tr_q = self.data.positions(np.asarray(self.data.train, np.int64))
        axis, off = plane_candidates(np.concatenate([tr_x, tr_y, tr_q]))
        A, b = (np.stack(m) for m in zip(*(reflection(a, o) for a, o in zip(axis, off))))
        score = np.zeros(len(A), np.complex128)
        for i in range(0, len(self.idx), CHUNK):    # the gradient is a sum over views: by chunks
            sl = slice(i * 16, (i + CHUNK) * 16)
            vi = Views.of(self.data, self.idx[i:i + CHUNK])
            g = field.image_gain_gradients(vi, gr[sl], gi[sl], A, b)
            score = score + g[:, 0] + 1j * g[:, 1]
        rel = np.abs(score)
        ex_axis, ex_off = field.single_planes()
        pick = pick_planes(rel, axis, off, count=self.planes, existing_axis=ex_axis, existing_offset=ex_off)
        planes = [(int(axis[i]), float(off[i])) for i in pick]
        event = {"event": "pursuit", "planes": [{"axis": "xyz"[a], "offset_m": round(o, 3), "score": float(rel[i])}
                                                for (a, o), i in zip(planes, pick)],
                 "images_added": 0}
        if not planes:
            return event
        nA, nb, norder = new_images(field, planes, max_order=field.cfg.image_order)
        box = np.asarray(field.params["vis_grid_box"].numpy(), np.float64) if "vis_grid_box" in field.params \
            else None
        centre = (box[:3] + box[3:]) / 2 if box is not None else tr_q.mean(0)
        where = field.add_images(nA, nb, norder, vis_center=centre)
        for k, pos in where.items():
            if self.prefix + k in opt.state:
                move_adam_state(opt, self.prefix + k, field.params[k], src=np.arange(len(pos)), dst=pos)
        event["images_added"] = int(len(nA))
        event["n_gaussians"] = int(field.num_primitives)
        return event

    def state_dict(self) -> dict:
        return {"pursuit_done": np.asarray(self.done, np.int64)}

    def load_state_dict(self, state: dict) -> None:
        self.done = [int(s) for s in np.asarray(state.get("pursuit_done", np.zeros(0, np.int64))).ravel()]


def pursuit_for(field, *, data, fit: np.ndarray, frozen: list, downsample: int, prefix: str, iterations: int,
                loss_fn) -> PlanePursuit | None:
    """The :class:`PlanePursuit` of ``field`` when it is an unknown room's coherent Gaussian field
    whose ``pursuit`` is on (:func:`~rfmitsuba.models.coherent_gaussians.uses_pursuit`; "auto":
    where ``data``'s positions spread wider than the array's beam) with ``pursuit_planes`` > 0
    (else None)."""
    if not isinstance(field, CoherentGaussianField) or field.init != "data" or field.cfg.pursuit_planes <= 0 \
            or field.frozen or iterations < 2 or not uses_pursuit(field.cfg, data):
        return None
    c = field.cfg
    return PlanePursuit(data=data, fit=fit, frozen=frozen, downsample=downsample, prefix=prefix,
                        iterations=iterations, planes=c.pursuit_planes, at=tuple(c.pursuit_at),
                        views=c.pursuit_views, loss_fn=loss_fn)
