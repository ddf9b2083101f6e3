"""The training views of one dataset state: :class:`TrainData`.

It opens a dataset folder, a NeRF2 spectrum folder or One Walk folders (:func:`rfmitsuba.data.store.open_dataset`)
and gives, per antenna index, the min-max normalised PAS (optionally block-averaged by
:func:`downsample`), the positions of the array, the transmitter and the moving device
(moving RX: the array moves; moving TX: the transmitter moves, the array is fixed), the array
frame, the split, the carrier and the scene's meshes where the dataset names a scene.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..core.errors import DatasetError
from ..rf.bartlett_ref import (
    normalize as minmax,  # the project's per-image min-max normalisation, [..., H, W] -> [0, 1]
)
from ..rf.grid import PAS_SHAPE
from .nerf2 import quaternion_matrix
from .scene_xml import read_shapes
from .store import open_dataset


#: samples per chunk of :func:`normalised_pas` (its peak memory besides the result: 1024 raw PAS, 133 MB)
PAS_CHUNK = 1024


def normalised_pas(idx: np.ndarray, raw, *, d: int, bad) -> np.ndarray:
    """Min-max normalised ``d x d`` block means of the PAS of samples ``idx``, :data:`PAS_CHUNK`
    at a time (a walk dataset's 20 000 training samples are 2.6 GB at 90 x 360).

    Args:
        idx: int [K] sample indices.
        raw: callable (int [k] indices) -> float [k, 90, 360] raw PAS.
        d: block size.
        bad: callable (one index) -> the message naming that sample when its PAS holds NaN or inf.

    Returns:
        float32 [K, 90/d, 360/d].

    Raises:
        DatasetError: ``bad``'s message for the first sample with NaN/inf values.
    """
    idx = np.asarray(idx, np.int64)
    out = np.empty((len(idx), PAS_SHAPE[0] // d, PAS_SHAPE[1] // d), np.float32)
    for c0 in range(0, len(idx), PAS_CHUNK):
        part = idx[c0:c0 + PAS_CHUNK]
        x = np.asarray(raw(part), np.float32)
        finite = np.isfinite(x).all(axis=(1, 2))
        if not finite.all():
            raise DatasetError(bad(int(part[int(np.flatnonzero(~finite)[0])])))
        out[c0:c0 + len(part)] = minmax(downsample(x, d))
    return out


@dataclass(frozen=True)
class PasRows:
    """The normalised PAS of some samples, read when indexed: ``len(r)`` samples, ``r[i]``
    (int [k] positions into ``rows``) gives float32 [k, H, W] from ``read(rows[i])``. Code that
    needs a few of many PAS (the neighbour floors) or all of them one chunk at a time (the mean
    image) takes one instead of the whole array.

    Attributes:
        rows: int64 [M] the samples, in order.
        read: callable (int64 [k] samples) -> float32 [k, H, W] normalised PAS.
    """

    rows: np.ndarray
    read: Callable[[np.ndarray], np.ndarray]

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, i) -> np.ndarray:
        i = np.asarray(i, np.int64)
        if i.ndim != 1:
            raise IndexError(f"PasRows: index with an int array [k], not shape {i.shape}")
        return self.read(self.rows[i])


def downsample(x: np.ndarray, d: int) -> np.ndarray:
    """Block means of d x d pixels: float [K, H, W] -> [K, H/d, W/d]."""
    if d == 1:
        return np.asarray(x, dtype=np.float32)
    k, h, w = x.shape
    blocks = np.asarray(x, np.float32).reshape(k, h // d, d, w // d, d)
    out = np.zeros((k, h // d, w // d), np.float32)
    for i in range(d):          # d*d strided adds: about 3 times faster than mean(axis=(2, 4))
        for j in range(d):
            out += blocks[:, :, i, :, j]
    out *= np.float32(1.0 / (d * d))
    return out


def _scene_xml(meta: dict, root: Path) -> Path | None:
    """The scene XML a dataset was simulated in (meta "scene": {"file", "name"} or a string), or None."""
    sc = meta.get("scene")
    cands = []
    if isinstance(sc, dict):
        cands = [sc.get("file"), sc.get("name")]
    elif isinstance(sc, str):
        cands = [sc]
    for v in cands:
        if not isinstance(v, str) or not v:
            continue
        p = Path(v) if Path(v).is_absolute() else root / v
        if p.suffix.lower() == ".xml" and p.is_file():
            return p
        try:
            from ..scenes import path as scene_path

            return Path(scene_path(Path(v).stem))
        except Exception:  # noqa: BLE001 - not a built-in scene name
            continue
    return None


def varies_by_measurement(meta: dict, *, measured: bool = False) -> bool:
    """Whether a dataset's spectra vary from one measurement to the next beyond what a field of
    the stated positions draws.

    Measured spectra do (docs/results/measured/diagnosis.md: the measured NeRF2 RFID spectra of
    tags 1-2 cm apart are less alike than any field at the carrier allows). So: True for measured
    data (``measured``: a NeRF2 folder as published) and for any dataset whose metadata records no
    ray tracer (no ``"solver"``: measured spectra in another folder format, or written beside an
    ``rfmitsuba.json`` of the user's), and for a simulation with a measurement drift (``"impairments":
    {"drift": {...}}``, :func:`rfmitsuba.sim.nerf2like.measurement_drift`); False for a ray-traced
    simulation without one. A NeRF2 folder's own metadata is read from its ``rfmitsuba.json``
    (``meta["nerf2"]``).
    """
    own = meta.get("nerf2") if isinstance(meta.get("nerf2"), dict) else meta
    if measured or not isinstance(own.get("solver"), dict):
        return True
    impairments = own.get("impairments")
    return isinstance(impairments, dict) and bool(impairments.get("drift"))


def _max_depth(meta: dict, root: Path) -> int | None:
    """The simulating ray tracer's path depth (meta "solver": {"max_depth": n}), or None."""
    solver = meta.get("solver")
    if not isinstance(solver, dict) or solver.get("max_depth") is None:
        return None
    d = solver["max_depth"]
    if isinstance(d, bool) or not isinstance(d, int) or d < 0:
        raise DatasetError(f"{root}: solver.max_depth must be an integer >= 0, got {d!r}")
    return d


#: Sionna RT's shortest path segment [m] (``sionna.rt.constants.MIN_SEGMENT_LENGTH`` of the
#: Sionna RT 1.x/2.x the datasets were made with): its image method drops a path with two vertices
#: (ends, reflections, surface crossings) this close or closer. tests/data check it against the
#: installed Sionna.
SIONNA_MIN_SEGMENT_M = 1e-2


def _min_segment(meta: dict, root: Path) -> float | None:
    """The simulating ray tracer's shortest path segment [m] (meta "solver": {"min_segment_m"},
    else Sionna RT's where a solver is recorded), or None (no tracer made the data)."""
    solver = meta.get("solver")
    if not isinstance(solver, dict):
        return None
    v = solver.get("min_segment_m", SIONNA_MIN_SEGMENT_M)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (np.isfinite(v) and v >= 0):
        raise DatasetError(f"{root}: solver.min_segment_m must be a finite length >= 0 [m], got {v!r}")
    return float(v)


@dataclass
class TrainData:
    """What a run trains and is evaluated on.

    antenna_pos: float64 [A, 3] metres, moving device per position; view_pos: float64 [A, 3]
    metres, where the array is (= antenna_pos for task "rx", the fixed array for "tx");
    rx_to_world: float64 [3, 3] or None (array frame); train / test: int64 antenna indices;
    scene_xml: path or None; transmitter: float64 [3] metres or None (the fixed transmitter of task
    "rx"; in task "tx" the transmitter is the moving device, ``antenna_pos``; as
    :class:`rfmitsuba.models.base.Views` names the views' positions);
    bounds: (lo [3], hi [3]) metres of everything known (positions, scene); frequency_hz: carrier.
    """

    path: Path
    task: str
    antenna_pos: np.ndarray
    view_pos: np.ndarray
    rx_to_world: np.ndarray | None
    train: np.ndarray
    test: np.ndarray
    scene_xml: Path | None
    transmitter: np.ndarray | None
    bounds: tuple
    _pas: object = None
    state: int = 0
    #: carrier, Hz
    frequency_hz: float = 2.4e9
    #: how the dataset's PAS were read out: "amplitude" (our simulations) or "phase_only" (NeRF2's
    #: tool: each element's phase with unit magnitude)
    readout: str = "amplitude"
    #: measured data (a NeRF2 folder as published, not written by this package): exact geometry
    #: and impairments are unknown, so models should expect calibration errors
    measured: bool = False
    #: the spectra vary from one measurement to the next beyond what a field of position draws
    #: (:func:`varies_by_measurement`): measured, or simulated with a measurement drift
    varies_by_measurement: bool = False
    #: most interactions (reflections and surface crossings) per path of the ray tracer that
    #: simulated the data (meta "solver": {"max_depth"}), None when no tracer made it (measured data)
    max_depth: int | None = None
    #: the shortest segment between two vertices of a path that the simulating ray tracer keeps [m]
    #: (Sionna RT: 1 cm), None when no tracer made the data
    min_segment: float | None = None

    @classmethod
    def open(cls, path: str | Path, *, state: int = 0) -> "TrainData":
        """Open a dataset folder (or NeRF2 spectrum folder, or One Walk folder) for training on ``state``.

        Raises:
            DatasetError: missing folder/arrays, mismatched shapes, unknown task.
        """

        path = Path(path)
        if not path.exists():
            raise DatasetError(f"dataset {path} does not exist")
        ds = open_dataset(path)
        task = getattr(ds, "task", None)
        if task not in ("rx", "tx"):
            raise DatasetError(f"{path}: task must be 'rx' or 'tx', got {task!r}")
        if not 0 <= state < int(getattr(ds, "num_states", 1)):
            raise DatasetError(f"{path}: state {state} does not exist (dataset has {ds.num_states} states)")
        if hasattr(ds, "verify_state"):      # a chunk corrupted in place is found before it is fitted or scored
            ds.verify_state(state)
        ap = np.asarray(ds.antenna_pos, dtype=np.float64)
        if ap.ndim != 2 or ap.shape[1] != 3:
            raise DatasetError(f"{path}: antenna_pos has shape {ap.shape}, expected [A, 3]")
        if not np.isfinite(ap).all():
            raise DatasetError(f"{path}: antenna_pos has non-finite values (row {int(np.flatnonzero(~np.isfinite(ap).all(1))[0])})")
        fixed = np.asarray(getattr(ds, "fixed_pos", np.zeros(3)), dtype=np.float64).reshape(3)
        meta = dict(getattr(ds, "meta", {}) or {})
        r2w = getattr(ds, "rx_to_world", None)
        if r2w is None and "gateway_orientation_xyzw" in meta:
            r2w = quaternion_matrix(meta["gateway_orientation_xyzw"])
        r2w = None if r2w is None else np.asarray(r2w, dtype=np.float64).reshape(3, 3)
        view = ap.copy() if task == "rx" else np.tile(fixed, (len(ap), 1))
        sp = ds.split
        train = np.asarray(sp.antenna_train, dtype=np.int64)
        test = np.asarray(sp.antenna_test, dtype=np.int64)
        if len(train) == 0 or len(test) == 0:
            raise DatasetError(f"{path}: the split has {len(train)} training and {len(test)} test positions; both must be > 0")
        xml = _scene_xml(meta, path)
        measured = bool(getattr(ds, "measured", False))
        pts = np.concatenate([ap, fixed[None]])
        bounds = (pts.min(0), pts.max(0))
        data = cls(path=path, task=task, antenna_pos=ap, view_pos=view, rx_to_world=r2w, train=train, test=test,
                   scene_xml=xml, transmitter=fixed if task == "rx" else None, bounds=bounds, state=state,
                   frequency_hz=float(getattr(ds, "frequency_hz", 2.4e9)),
                   readout=str(getattr(ds, "readout", "amplitude")), measured=measured,
                   varies_by_measurement=varies_by_measurement(meta, measured=measured),
                   max_depth=_max_depth(meta, path), min_segment=_min_segment(meta, path))
        data._pas = ds.pas(state)
        shp = tuple(np.shape(data._pas))
        if shp != (len(ap), *PAS_SHAPE):
            raise DatasetError(f"{path}: pas of state {state} has shape {shp}, expected ({len(ap)}, 90, 360)")
        return data

    def pas(self, idx: np.ndarray, *, d: int = 1) -> np.ndarray:
        """Min-max normalised PAS of antenna indices ``idx``: float32 [K, 90/d, 360/d]
        (:func:`normalised_pas`).

        Raises:
            DatasetError: a PAS with NaN/inf values (naming the antenna index).
        """
        def raw(part):
            order = np.argsort(part)       # a memmap reads sorted rows fastest
            out = np.empty((len(part), *PAS_SHAPE), np.float32)
            out[order] = self._pas[part[order]]
            return out

        return normalised_pas(idx, raw, d=d, bad=lambda k: f"{self.path}: PAS of antenna position {k} "
                                                          f"(state {self.state}) contains NaN or infinite values")

    def positions(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(array centre x, transmitter y, moving device q), each float64 [K, 3] metres, of
        indices ``idx``: moving RX has x = q and y the fixed corner; moving TX has x the fixed
        array and y = q."""
        idx = np.asarray(idx, np.int64)
        q = np.asarray(self.antenna_pos[idx], np.float64)
        x = np.asarray(self.view_pos[idx], np.float64)
        y = q if self.task == "tx" else np.tile(np.asarray(self.transmitter, np.float64), (len(idx), 1))
        return x, y, q

    def positions_at(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(array centre x, transmitter y), each float64 [K, 3] metres, with the moving device at
        ``q`` (float [K, 3] m, anywhere: positions the dataset does not hold) and the fixed device
        where the dataset has it, as :meth:`positions`."""
        q = np.asarray(q, np.float64).reshape(-1, 3)
        if self.task == "tx":
            return np.tile(np.asarray(self.view_pos[0], np.float64), (len(q), 1)), q
        return q, np.tile(np.asarray(self.transmitter, np.float64), (len(q), 1))

    def meshes(self, scene_xml: Path | None = None):
        """Scene meshes, list of (vertices float64 [V, 3], faces int64 [F, 3]) in metres, of
        ``scene_xml`` (default the dataset's scene), or None when there is none (NeRF2 folders)."""
        scene_xml = scene_xml or self.scene_xml
        if scene_xml is None:
            return None

        return [(np.asarray(sh.mesh.vertices, np.float64), np.asarray(sh.mesh.faces, np.int64))
                for sh in read_shapes(scene_xml)]
