"""Predictions of a trained Stage-1 run at positions of the user's choice (``rfmitsuba predict``).

A run is evaluated on its own test split by :func:`rfmitsuba.eval.run.evaluate_run`; this module
renders it anywhere else: a grid for a coverage map, a trajectory, another tool's test positions.
The positions are the moving device's (the receiver array's centre in the moving-RX task, the
transmitter in the moving-TX task); the fixed device, the array's orientation and the carrier
come from the run's dataset.

:func:`predict_run` returns the PAS min-max normalised per image (the metric protocol's scale,
docs/conventions.md), optionally as the neighbour-anchored prediction
(:mod:`rfmitsuba.eval.anchor`) with the ``(k, alpha)`` that ``rfmitsuba eval`` chose on the
run's validation positions. :func:`write_prediction` writes them as a NeRF2-style folder::

    OUT/pas.npy            float32 [K, 90, 360] in [0, 1]
    OUT/spectrum/00001.png 8-bit greyscale, row = elevation (SPEC layout), one per position
    OUT/positions.csv      x,y,z [m], one row per image, in the order given
    OUT/predict.json       run, dataset, task, count, how the PAS were made

Bad input is named: a malformed or non-finite positions file (with its line), a position
outside a known room or inside its furniture (:meth:`rfmitsuba.sim.geometry.RoomGeometry.check_points`),
an anchored prediction asked of a run that was never evaluated.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..core.atomic import write_json
from ..core.errors import ConfigError, DatasetError, PlacementError, RunError
from ..core.folder_lock import holds_work
from ..models.base import FieldSet, Views
from ..models.coherent_gaussians import outside_room_box
from ..rf.bartlett_ref import normalize as minmax
from ..train.trainer import load_run
from .anchor import anchored


def read_positions(path: str | Path) -> np.ndarray:
    """Positions [m] from ``path``: a ``.npy`` array [K, 3], or text read as a NeRF2 ``tx_pos.csv``
    (:func:`rfmitsuba.data.nerf2.read_positions`: x, y, z per line, separated by commas or white
    space; a header row, which may name the x, y and z columns; blank lines and CRLF).

    Returns:
        float64 [K, 3], K >= 1, every value finite.
    Raises:
        DatasetError naming the file (and the line) when it is missing, malformed or not finite.
    """
    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"positions file {p} does not exist")
    if p.suffix == ".npy":
        try:
            a = np.load(p, allow_pickle=False)
        except (ValueError, OSError) as e:
            raise DatasetError(f"{p}: not a NumPy array file ({e})") from None
        a = np.asarray(a, np.float64) if np.issubdtype(np.asarray(a).dtype, np.number) else None
        if a is None or a.ndim != 2 or a.shape[1] != 3 or len(a) == 0:
            raise DatasetError(f"{p}: expected a numeric array of shape [K, 3], K >= 1")
        bad = np.flatnonzero(~np.isfinite(a).all(1))
        if len(bad):
            raise DatasetError(f"{p}: row {int(bad[0])} is not finite: {a[bad[0]].tolist()}")
        return a
    from ..data.nerf2 import read_positions as read_text_positions

    return read_text_positions(p)


def views_at(data, positions: np.ndarray) -> Views:
    """The views of a dataset's geometry with the moving device at ``positions`` (float [K, 3] m):
    moving RX puts the array there, the transmitter at the dataset's fixed source; moving TX the
    transmitter there, the array at the dataset's fixed position."""
    q = np.asarray(positions, np.float64).reshape(-1, 3)
    x, y = data.positions_at(q)
    return Views(antenna_pos=q, view_pos=x, transmitter=y, rx_to_world=data.rx_to_world,
                 frequency_hz=float(data.frequency_hz), task=data.task)


def render_at(renderer: FieldSet, data, positions: np.ndarray, *, batch: int = 8) -> np.ndarray:
    """Raw PAS of the run's fields at ``positions`` (float [K, 3] [m]): float32 [K, 90, 360]."""
    import drjit as dr

    from ..models.base import render

    if any(f.extra_inputs or f.person for f in renderer.fields):
        raise ConfigError("predict renders Stage-1 fields only (this run's field takes per-view inputs)")
    q = np.asarray(positions, np.float64).reshape(-1, 3)
    out = np.zeros((len(q), 90, 360), np.float32)
    for i in range(0, len(q), batch):
        with dr.suspend_grad():
            img = render(renderer.fields, views_at(data, q[i:i + batch]), height=90, width=360, normalize=False)
        out[i:i + batch] = np.asarray(img.numpy(), np.float32).reshape(-1, 90, 360)
    return out


#: how far [m] past the box of its training positions a field of an unknown room (no scene,
#: no ``coherent_gaussians.room_box``) is asked to predict: the block split's slab is within
#: about 0.1 m of its data; at 2 m the fields' image sources and scatterers no longer describe
#: the position, and far outside the data (100 m) the field renders a constant image
UNKNOWN_ROOM_MARGIN_M = 1.0


def _check_training_region(data, q: np.ndarray) -> None:
    """An unknown room trained without its dimensions: refuse a position more than
    :data:`UNKNOWN_ROOM_MARGIN_M` outside the box of the data's moving-device positions, naming it
    (PlacementError)."""
    pos = np.asarray(data.antenna_pos, np.float64)
    lo, hi = pos.min(0) - UNKNOWN_ROOM_MARGIN_M, pos.max(0) + UNKNOWN_ROOM_MARGIN_M
    outside = ((q < lo) | (q > hi)).any(1)
    if outside.any():
        i = int(np.argmax(outside))
        more = f" ({int(outside.sum()) - 1} more position(s) are outside too)" if outside.sum() > 1 else ""
        raise PlacementError(
            f"position {i} at ({', '.join(f'{v:.3f}' for v in q[i])}) is more than {UNKNOWN_ROOM_MARGIN_M:g} m "
            f"outside the box of the run's training positions ({', '.join(f'{v:.3f}' for v in pos.min(0))}) to "
            f"({', '.join(f'{v:.3f}' for v in pos.max(0))}) m, in a room the run does not know; the field does not "
            f"describe it there{more} (--no-room-check renders it anyway)")


def _check_room_box(renderer: FieldSet, q: np.ndarray, data=None) -> None:
    """An unknown room trained with its dimensions (``coherent_gaussians.room_box``): refuse a
    position outside that box, naming it (PlacementError). Without the box, a position far
    outside the training positions (:func:`_check_training_region`, when ``data`` is given)."""
    for f in renderer.fields:
        box = getattr(getattr(f, "cfg", None), "room_box", None)
        if box is None:
            continue
        box = np.asarray(box, np.float64)
        outside = outside_room_box(box, q)
        if outside.any():
            i = int(np.argmax(outside))
            more = f" ({int(outside.sum()) - 1} more position(s) are outside too)" if outside.sum() > 1 else ""
            raise PlacementError(f"position {i} at ({', '.join(f'{v:.3f}' for v in q[i])}) is outside the room box "
                                 f"{box.tolist()} m the run was trained with (coherent_gaussians.room_box){more}")
        return
    if data is not None:
        _check_training_region(data, q)


def predict_run(run_dir: str | Path, positions: np.ndarray, *, anchor: bool = False, batch: int = 8,
                check_room: bool = True) -> dict:
    """Render a finished run at ``positions`` (float [K, 3] m, the moving device).

    Args:
        anchor: the neighbour-anchored prediction with the ``(k, alpha)`` that ``rfmitsuba eval``
            chose (RUN/eval/metrics.json); where it chose the field alone, the field's PAS.
        check_room: in a known room, refuse positions outside it or inside its furniture; in an
            unknown room trained with ``coherent_gaussians.room_box``, positions outside that box.
    Returns:
        {"pas": float32 [K, 90, 360] in [0, 1], "positions": float64 [K, 3], "how": "field" or
        "anchored k=.. alpha=..", "run", "dataset", "task"}; for a field that states its uncertainty
        (the Gaussian-process field) also "predictive_sd": float64 [K], the posterior standard
        deviation of a pixel of the normalised training spectra's scale at each position, and
        "prior_sd", what it grows to far from the data.
    Raises:
        RunError (not a finished run; anchored without an evaluation), PlacementError (a position
        outside the room), ConfigError (bad positions array).
    """
    rd = Path(run_dir)
    q = np.asarray(positions, np.float64)
    if q.ndim != 2 or q.shape[1] != 3 or len(q) == 0 or not np.isfinite(q).all():
        raise ConfigError(f"positions must be a finite array [K, 3] with K >= 1, got shape {q.shape}")
    _, data, renderer = load_run(rd)
    if check_room and data.scene_xml is not None:
        from ..sim.geometry import RoomGeometry

        try:
            RoomGeometry.from_xml(data.scene_xml).check_points(q, what="position")
        except PlacementError as e:   # the way out, as for an unknown room's box
            raise PlacementError(f"{e} (--no-room-check renders it anyway)") from None
    elif check_room:
        _check_room_box(renderer, q, data)
    how = "field"
    choice = None
    if anchor:
        mfile = rd / "eval" / "metrics.json"
        if not mfile.is_file():
            raise RunError(f"{rd}: no evaluation; run `rfmitsuba eval {rd}` first (the anchored prediction's "
                           "(k, alpha) are chosen there on the run's validation positions)")
        choice = json.loads(mfile.read_text()).get("anchored")
        if choice is None:
            raise RunError(f"{mfile}: this run has no validation positions, so no anchored prediction was chosen")
    raw = render_at(renderer, data, q, batch=batch)
    r64 = np.asarray(raw, np.float64).reshape(len(q), -1)
    span = r64.max(1) - r64.min(1)
    flat = ~np.isfinite(span) | (span <= 1e-9 * np.maximum(np.abs(r64).max(1), 1e-30))
    if flat.any():          # min-max normalising a constant image would write zeros as if they were a PAS
        i = int(np.argmax(flat))
        raise RunError(f"the field renders a constant (or non-finite) image at position {i} "
                       f"({', '.join(f'{v:.3f}' for v in q[i])}){f' and {int(flat.sum()) - 1} more' if flat.sum() > 1 else ''}: "
                       "it has no signal there to normalise; nothing was written")
    pred = minmax(raw)
    if choice is not None and choice.get("use") != "field":
        split = json.loads((rd / "split.json").read_text())
        train_idx = np.asarray(split["train"], np.int64)
        field_train = minmax(renderer.render(data, train_idx, batch=batch))
        pred = anchored(pred, field_train, data.pas(train_idx), data.antenna_pos[train_idx], q,
                        k=int(choice["k"]), alpha=float(choice["alpha"]))
        how = f"anchored k={int(choice['k'])} alpha={float(choice['alpha']):g}"
    out = {"pas": np.asarray(pred, np.float32), "positions": q, "how": how, "run": str(rd),
           "dataset": str(data.path), "task": data.task}
    fields = getattr(renderer, "fields", [])
    if len(fields) == 1 and hasattr(fields[0], "predictive_sd"):      # a field that states its uncertainty
        f = fields[0]
        out["predictive_sd"] = np.asarray(f.predictive_sd(q), np.float64)
        out["prior_sd"] = f.prior_sd
    return out


def new_folder(out: str | Path) -> Path:
    """``out`` as a Path if it is new or empty, else RunError: a prediction never overwrites one."""
    o = Path(out)
    if o.exists() and (not o.is_dir() or holds_work(o)):
        raise RunError(f"{o} is not an empty folder; choose a new one for the prediction")
    return o


def write_prediction(out: str | Path, result: dict) -> Path:
    """Write :func:`predict_run`'s result as the folder of the module docstring. ``out`` must be new
    or empty (:func:`new_folder`)."""
    from ..data.nerf2 import write_positions, write_spectra

    o = new_folder(out)
    o.mkdir(parents=True, exist_ok=True)
    np.save(o / "pas.npy", result["pas"])
    write_spectra(o, result["pas"])
    write_positions(o / "positions.csv", result["positions"])
    write_json(o / "predict.json", {k: result[k] for k in ("run", "dataset", "task", "how")}
               | {"count": len(result["positions"])}
               | ({"predictive_sd": [float(v) for v in result["predictive_sd"]], "prior_sd": result["prior_sd"]}
                  if "predictive_sd" in result else {}))
    return o
