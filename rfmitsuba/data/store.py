"""The on-disk PAS dataset: folder layout, atomic per-state chunks, splits.

Layout of one dataset folder (format ``rfmitsuba-dataset/1``)::

    meta.json          configuration, reproducibility record, units
    split.json         antenna / person train-test indices and their seed
    antenna_pos.npy    float32 [A, 3], metres, world frame
    chunks/00000/      state 0: the empty room
        pas.npy        float32 [A, 90, 360], raw linear Bartlett amplitude
        channel.npy    complex64 [A, 16], narrowband channel per element
        chunk.json     sha256 of both arrays (checked by Dataset.verify)
    chunks/00001/ ...  state s > 0: the person at meta["person_positions"][s-1]

Each chunk folder is written under a temporary name and renamed when
complete, so a folder named ``chunks/<state:05d>`` is either whole or was
damaged afterwards. The flattened view (``Dataset.arrays``) has row
``k = state * A + antenna``.

Nothing here needs Sionna: :func:`write_dataset` makes small synthetic
datasets for other modules' tests; :mod:`rfmitsuba.sim.simulate` generates real ones.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from ..core.atomic import write_json
from ..core.config import differences
from ..core.direct_io import save_npy, save_npy_blocks
from ..core.errors import DatasetError, SceneError
from ..core.folder_lock import holds_work
from ..core.legacy_names import current_keys
from ..rf import array as antenna
from ..rf.array import NUM_ELEMENTS
from ..rf.grid import PAS_SHAPE
from . import nerf2, one_walk
from .split import Split, make_split

FORMAT = "rfmitsuba-dataset/1"






UNITS = {
    "positions": "metres, world frame (scene XML), z up",
    "angles": "radians unless the key ends in _deg",
    "frequency_hz": "hertz",
    "pas": "linear Bartlett amplitude |sum_m conj(a_m) h_m| / 16, raw (not normalised)",
    "channel": "complex baseband narrowband channel per element, unitless (sqrt of path gain)",
}


def chunk_name(state: int) -> str:
    """Folder name of one state's chunk, e.g. ``00003``."""
    return f"{int(state):05d}"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 22), b""):
            h.update(block)
    return h.hexdigest()


def _write_meta_json(path: Path, obj: Any) -> None:
    write_json(path, obj, sort_keys=True, allow_nan=False, end="\n")


def _jsonable(v: Any) -> Any:
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return _jsonable(v.tolist())
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, Path):
        return str(v)
    return v


def write_chunk(root: str | Path, state: int, *, pas: np.ndarray | None = None, channel: np.ndarray | None = None,
                pas_blocks=None) -> Path:
    """Write one state's arrays atomically (temporary folder, then rename).

    Args:
        root: dataset folder.
        state: state index s (0 = empty room).
        pas: float32 [A, 90, 360], raw linear amplitude; or
        pas_blocks: the same as blocks float32 [a_k, 90, 360] in order (A = ``channel``'s rows),
            each written as it comes, so the whole state is never held at once (a generator
            that beamforms into one reused buffer); needs ``channel``.
        channel: complex64 [A, 16] or None (zeros are stored then).
    Returns:
        The chunk folder. An existing chunk of that state is replaced; a failure (blocks that
        do not add up to A rows) leaves it as it was.
    """
    root = Path(root)
    if (pas is None) == (pas_blocks is None):
        raise DatasetError(f"state {state}: give pas or pas_blocks (one of them)")
    if pas is not None:
        pas = np.ascontiguousarray(pas, dtype=np.float32)
        if pas.ndim != 3 or pas.shape[1:] != PAS_SHAPE:
            raise DatasetError(f"state {state}: pas must be [A, 90, 360], got {pas.shape}")
        num = pas.shape[0]
    elif channel is None:
        raise DatasetError(f"state {state}: pas_blocks needs the channel (its rows give the number of PAS)")
    else:
        num = int(np.shape(channel)[0])
    if channel is None:
        channel = np.zeros((num, NUM_ELEMENTS), np.complex64)
    channel = np.ascontiguousarray(channel, dtype=np.complex64)
    if channel.shape != (num, NUM_ELEMENTS):
        raise DatasetError(f"state {state}: channel must be [{num}, 16], got {channel.shape}")
    chunks = root / "chunks"
    chunks.mkdir(parents=True, exist_ok=True)
    final = chunks / chunk_name(state)
    tmp = chunks / f".tmp-{chunk_name(state)}-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    # the arrays go to the device past the page cache, hashed as they are written
    # (rfmitsuba.core.direct_io: 0.074-0.091 s for a 117 MB state against 0.39-0.40 s)
    try:
        digests = {"pas.npy": (save_npy(tmp / "pas.npy", pas) if pas is not None else
                               save_npy_blocks(tmp / "pas.npy", pas_blocks, shape=(num, *PAS_SHAPE))),
                   "channel.npy": save_npy(tmp / "channel.npy", channel)}
    except BaseException as e:              # nothing half-written stays behind
        shutil.rmtree(tmp, ignore_errors=True)
        if type(e) is ValueError:           # the blocks' shapes (save_npy_blocks)
            raise DatasetError(f"state {state}: {e}") from None
        raise
    _write_meta_json(tmp / "chunk.json", {"state": int(state), "num_antennas": num, "sha256": digests})
    with open(tmp / "chunk.json", "rb") as fh:  # every file on disk before the rename makes the chunk visible
        os.fsync(fh.fileno())
    if final.exists():
        shutil.rmtree(final)
    os.rename(tmp, final)
    return final


def remove_stale_tmp(root: str | Path) -> int:
    """Delete unfinished chunk folders (never renamed); returns how many."""
    chunks = Path(root) / "chunks"
    n = 0
    if chunks.is_dir():
        for p in chunks.glob(".tmp-*"):
            shutil.rmtree(p, ignore_errors=True)
            n += 1
    return n


def check_chunk(root: str | Path, state: int, num_antennas: int, *, full: bool = False) -> None:
    """Raise DatasetError naming the chunk if it is missing, truncated or (``full``) corrupt.

    The quick check reads the .npy headers and compares file sizes; ``full``
    also compares sha256 digests with ``chunk.json``.
    """
    folder = Path(root) / "chunks" / chunk_name(state)
    name = f"chunk {folder}"
    if not folder.is_dir():
        raise DatasetError(f"{name} is missing")
    expect = {"pas.npy": ((num_antennas, *PAS_SHAPE), np.float32),
              "channel.npy": ((num_antennas, NUM_ELEMENTS), np.complex64)}
    for fname, (shape, dtype) in expect.items():
        f = folder / fname
        if not f.is_file():
            raise DatasetError(f"{name}: {fname} is missing")
        try:
            arr = np.load(f, mmap_mode="r", allow_pickle=False)
        except (ValueError, OSError, EOFError) as e:
            raise DatasetError(f"{name}: {fname} is truncated or corrupt ({e})") from None
        if arr.shape != shape or arr.dtype != dtype:
            raise DatasetError(f"{name}: {fname} has shape {arr.shape} {arr.dtype}, expected {shape} {np.dtype(dtype)}")
        del arr
    if full:
        try:
            digests = json.loads((folder / "chunk.json").read_text())["sha256"]
        except (OSError, ValueError, KeyError) as e:
            raise DatasetError(f"{name}: chunk.json is missing or malformed ({e})") from None
        for fname in expect:
            if _sha256(folder / fname) != digests.get(fname):
                raise DatasetError(f"{name}: {fname} does not match its sha256 in chunk.json (corrupt)")


class Dataset:
    """A dataset folder opened for reading (see module docstring).

    Attributes:
        path: the folder.
        meta: the parsed meta.json.
        task: "rx" (moving array) or "tx" (moving transmitter).
        frequency_hz: carrier, Hz.
        num_antennas: A.
        num_states: S = 1 + H.
        antenna_pos: float32 [A, 3], metres, positions of the moving device.
        person_pos: float32 [S, 3], metres (row 0 NaN: empty room).
        fixed_pos: float64 [3], metres, the fixed device in the room corner.
        split: the saved :class:`Split`.
    """

    def __init__(self, path: str | Path, *, check: bool = True):
        self.path = Path(path)
        meta_file = self.path / "meta.json"
        if not meta_file.is_file():
            raise DatasetError(f"{self.path}: no meta.json, not a dataset folder (rfmitsuba generate writes one); "
                               "a NeRF2 folder holds spectrum/ and tx_pos.csv, a One Walk folder spectrum/ or "
                               "spectrums/ and rx_info.csv or spectrum_info.csv")
        try:
            self.meta = current_keys(json.loads(meta_file.read_text()))
        except ValueError as e:
            raise DatasetError(f"{meta_file}: not valid JSON ({e})") from None
        if self.meta.get("format") != FORMAT:
            raise DatasetError(f"{meta_file}: format is {self.meta.get('format')!r}, expected {FORMAT!r}")
        for key in ("task", "frequency_hz", "num_antenna_positions", "person_positions", "fixed_pos"):
            if key not in self.meta:
                raise DatasetError(f"{meta_file}: missing key {key!r}")
        self.task = self.meta["task"]
        self.frequency_hz = float(self.meta["frequency_hz"])
        self.num_antennas = int(self.meta["num_antenna_positions"])
        hp = np.asarray(self.meta["person_positions"], dtype=np.float32).reshape(-1, 3)
        self.num_states = 1 + hp.shape[0]
        self.person_pos = np.concatenate([np.full((1, 3), np.nan, np.float32), hp])
        others = (self.meta.get("other_people") or {}).get("positions") if isinstance(self.meta.get("other_people"),
                                                                                      dict) else None
        op = np.zeros((len(hp), 0, 3), np.float32)
        if others is not None and len(hp):
            op = np.asarray(others, np.float32).reshape(len(hp), -1, 3)
        #: float32 [S, P, 3] every person's feet [m] (person 1 is ``person_pos``; row 0 NaN: the empty room)
        self.people_pos = np.concatenate([self.person_pos[:, None, :],
                                          np.concatenate([np.full((1, op.shape[1], 3), np.nan, np.float32), op])],
                                         axis=1)
        self.fixed_pos = np.asarray(self.meta["fixed_pos"], dtype=np.float64)
        ap_file = self.path / "antenna_pos.npy"
        try:
            self.antenna_pos = np.load(ap_file, allow_pickle=False).astype(np.float32)
        except (OSError, ValueError, EOFError) as e:
            raise DatasetError(f"{ap_file}: missing or unreadable ({e})") from None
        if self.antenna_pos.shape != (self.num_antennas, 3):
            raise DatasetError(f"{ap_file}: shape {self.antenna_pos.shape}, expected ({self.num_antennas}, 3)")
        split_file = self.path / "split.json"
        try:
            sd = json.loads(split_file.read_text())
        except (OSError, ValueError) as e:
            raise DatasetError(f"{split_file}: missing or malformed ({e})") from None
        self.split = Split.from_json(sd, num_antennas=self.num_antennas, num_people=self.num_states - 1,
                                     where=str(split_file))
        if check:
            for s in range(self.num_states):
                check_chunk(self.path, s, self.num_antennas)

    def __repr__(self) -> str:
        return (f"Dataset({str(self.path)!r}, task={self.task!r}, antennas={self.num_antennas}, "
                f"states={self.num_states})")

    def pas(self, state: int) -> np.ndarray:
        """Raw PAS of one state: float32 [A, 90, 360] (read-only memmap)."""
        return self._load(state, "pas.npy")

    def channel(self, state: int) -> np.ndarray:
        """Narrowband channel of one state: complex64 [A, 16] (read-only memmap)."""
        return self._load(state, "channel.npy")

    def _load(self, state: int, fname: str) -> np.ndarray:
        if not 0 <= int(state) < self.num_states:
            raise DatasetError(f"{self.path}: state {state} outside [0, {self.num_states})")
        f = self.path / "chunks" / chunk_name(state) / fname
        try:
            return np.load(f, mmap_mode="r", allow_pickle=False)
        except (OSError, ValueError, EOFError) as e:
            raise DatasetError(f"chunk {f.parent}: {fname} unreadable ({e})") from None

    def fingerprint(self) -> str:
        """A hex digest that changes when the dataset's content does: sha256 over ``meta.json``,
        ``split.json``, ``antenna_pos.npy`` and every chunk's ``chunk.json`` (which holds the
        sha256 of its arrays). Reads a few kilobytes per state, not the arrays; results derived
        from the data alone (the evaluation floors) are cached under it.

        Raises:
            DatasetError: a chunk without ``chunk.json``.
        """
        h = hashlib.sha256()
        for f in (self.path / "meta.json", self.path / "split.json", self.path / "antenna_pos.npy"):
            h.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
        for s in range(self.num_states):
            f = self.path / "chunks" / chunk_name(s) / "chunk.json"
            try:
                h.update(f.read_bytes() + b"\0")
            except OSError as e:
                raise DatasetError(f"chunk {f.parent}: chunk.json unreadable ({e})") from None
        return h.hexdigest()

    def verify_state(self, state: int) -> None:
        """Full check (sha256 against ``chunk.json``) of one state's chunk, as training and
        evaluation open it; DatasetError naming the chunk and the way out when it fails. Costs one
        read of the chunk (state 0 of a 900-position dataset: 117 MB)."""
        try:
            check_chunk(self.path, int(state), self.num_antennas, full=True)
        except DatasetError as e:
            raise DatasetError(f"{e}; re-simulate it with `rfmitsuba generate` and --repair into {self.path} "
                               "(same options as it was made with)") from None

    def verify(self) -> list[int]:
        """Full check (sha256) of every chunk; returns the states whose chunk is bad or missing."""
        bad = []
        for s in range(self.num_states):
            try:
                check_chunk(self.path, s, self.num_antennas, full=True)
            except DatasetError:
                bad.append(s)
        return bad

    def arrays(self, states: list[int] | None = None) -> dict[str, np.ndarray]:
        """Flat arrays (docs/conventions.md), row ``k = state * A + antenna`` (over ``states`` in the given order).

        Returns:
            ``pas`` float32 [K, 90, 360], ``antenna_pos`` float32 [K, 3],
            ``person_pos`` float32 [K, 3] (NaN rows for the empty room),
            ``channel`` complex64 [K, 16], ``state`` int64 [K], ``antenna`` int64 [K].
        """
        states = list(range(self.num_states)) if states is None else [int(s) for s in states]
        A = self.num_antennas
        return {
            "pas": np.concatenate([np.asarray(self.pas(s)) for s in states]) if states
            else np.zeros((0, *PAS_SHAPE), np.float32),
            "channel": np.concatenate([np.asarray(self.channel(s)) for s in states]) if states
            else np.zeros((0, NUM_ELEMENTS), np.complex64),
            "antenna_pos": np.tile(self.antenna_pos, (len(states), 1)),
            "person_pos": np.repeat(self.person_pos[states], A, axis=0),
            "state": np.repeat(np.asarray(states, np.int64), A),
            "antenna": np.tile(np.arange(A, dtype=np.int64), len(states)),
        }


def open_dataset(path: str | Path, *, check: bool = True) -> Dataset:
    """Open a dataset folder; DatasetError naming the file/chunk when it is incomplete or damaged.

    A folder without ``meta.json`` in the One Walk layout (:func:`rfmitsuba.data.one_walk.layout`:
    a static folder, a dynamic one, or a folder holding both) is read through
    :func:`rfmitsuba.data.one_walk.read`; a NeRF2 spectrum folder (``spectrum/`` +
    ``tx_pos.csv``) through :func:`rfmitsuba.data.nerf2.read`.
    """
    p = Path(path)
    if not (p / "meta.json").exists():
        if one_walk.layout(p) is not None:
            return one_walk.read(p)
        if (p / "spectrum").is_dir():
            return nerf2.read(p)
    return Dataset(p, check=check)


#: keys compared first, so the reported difference is the cause rather than a consequence
_DIFF_FIRST = ("format", "task", "scene", "frequency_hz", "generate", "solver", "seeds", "num_antenna_positions",
               "num_states", "versions")


def first_difference(a: Any, b: Any) -> tuple[str, Any, Any] | None:
    """The first place where two meta dicts differ, the identifying keys first: (dotted key, the
    value in ``a``, the value in ``b``; "<missing>" where one lacks the key), or None when they
    are equal (:func:`rfmitsuba.core.config.differences`)."""
    return next(differences(a, b, first=_DIFF_FIRST, into_lists=True), None)


def _without_location(meta: dict) -> dict:
    """``meta`` without where the scene file lies (``scene.file``): the scene is identified by its
    name and content hashes, so one dataset resumes from another checkout or machine."""
    out = dict(meta)
    if isinstance(out.get("scene"), dict):
        out["scene"] = {k: v for k, v in out["scene"].items() if k != "file"}
    return out


def prepare_folder(path: str | Path, meta: dict, *, antenna_pos: np.ndarray, split: Split) -> Path:
    """Create the dataset folder (meta, split, antenna positions), or check an existing one matches.

    An existing ``meta.json`` of another configuration raises DatasetError naming
    the first differing key (the scene file's location does not count); nothing is overwritten then. A folder holding
    other files but no ``meta.json`` is refused too.
    """
    root = Path(path)
    meta = _jsonable(meta)
    meta_file = root / "meta.json"
    if meta_file.exists():
        try:
            old = current_keys(json.loads(meta_file.read_text()))
        except ValueError as e:
            raise DatasetError(f"{meta_file}: not valid JSON ({e}); refusing to overwrite") from None
        diff = first_difference(_without_location(old), _without_location(meta))
        if diff is not None:
            key, have, want = diff
            raise DatasetError(f"{root} holds a dataset of another configuration: {key} is {have!r} there and "
                               f"{want!r} in this call; nothing was overwritten (run the command that made it, "
                               "or choose another --out)")
        ap_old = np.load(root / "antenna_pos.npy", allow_pickle=False)
        if not np.array_equal(ap_old, np.asarray(antenna_pos, np.float32)):
            raise DatasetError(f"{root}/antenna_pos.npy differs from this configuration's positions")
        return root
    if root.exists() and holds_work(root):   # the writer's own lock aside
        raise DatasetError(f"{root} is not empty and holds no dataset; refusing to write into it")
    root.mkdir(parents=True, exist_ok=True)
    np.save(root / "antenna_pos.npy", np.asarray(antenna_pos, np.float32), allow_pickle=False)
    _write_meta_json(root / "split.json", split.to_json())
    _write_meta_json(meta_file, meta)  # last: its presence marks a prepared folder
    return root


def base_meta(*, task: str, frequency_hz: float, num_antennas: int, person_positions: np.ndarray,
              fixed_pos: np.ndarray, extra: dict | None = None) -> dict:
    """The meta.json keys every dataset has, plus ``extra`` (scene, solver, seeds, versions...)."""

    if task not in ("rx", "tx"):
        raise DatasetError(f"task must be 'rx' or 'tx', got {task!r}")
    hp = np.asarray(person_positions, np.float64).reshape(-1, 3)
    meta = {
        "format": FORMAT,
        "task": task,
        "frequency_hz": float(frequency_hz),
        "num_antenna_positions": int(num_antennas),
        "num_states": int(1 + hp.shape[0]),
        "person_positions": hp.tolist(),
        "fixed_pos": [float(x) for x in np.asarray(fixed_pos, np.float64).reshape(3)],
        "array": antenna.describe(float(frequency_hz)),
        "pas_layout": {"shape": list(PAS_SHAPE), "row": "elevation (i + 1) deg above the array plane",
                       "column": "azimuth j deg from array +x towards +y"},
        "units": UNITS,
    }
    meta.update(extra or {})
    return _jsonable(meta)


def write_dataset(path: str | Path, *, pas: np.ndarray, antenna_pos: np.ndarray, person_pos: np.ndarray,
                  meta: dict | None = None, split: Split | None = None, seed: int = 0,
                  channel: np.ndarray | None = None) -> Dataset:
    """Write a whole in-memory dataset (tests, converters); needs no Sionna.

    Args:
        path: new (or empty) folder.
        pas: float32 [S, A, 90, 360], raw or normalised amplitude.
        antenna_pos: float [A, 3], metres.
        person_pos: float [S, 3], metres; row 0 must be NaN (the empty room).
        meta: extra meta.json keys (e.g. ``task``, ``frequency_hz``, ``fixed_pos``, ``scene``).
        split: train/test split; default :func:`make_split` with ``seed``.
        seed: split seed when ``split`` is None.
        channel: complex64 [S, A, 16] or None.
    Returns:
        The written dataset, opened.
    """
    pas = np.asarray(pas, dtype=np.float32)
    if pas.ndim != 4 or pas.shape[2:] != PAS_SHAPE:
        raise DatasetError(f"pas must be [S, A, 90, 360], got {pas.shape}")
    S, A = pas.shape[:2]
    antenna_pos = np.asarray(antenna_pos, np.float64)
    if antenna_pos.shape != (A, 3) or not np.isfinite(antenna_pos).all():
        raise DatasetError(f"antenna_pos must be finite [{A}, 3], got shape {antenna_pos.shape}")
    person_pos = np.asarray(person_pos, np.float64)
    if person_pos.shape != (S, 3):
        raise DatasetError(f"person_pos must be [{S}, 3], got {person_pos.shape}")
    if not np.isnan(person_pos[0]).all() or not np.isfinite(person_pos[1:]).all():
        raise DatasetError("person_pos row 0 must be NaN (empty room) and rows 1.. finite")
    if channel is not None and np.shape(channel) != (S, A, NUM_ELEMENTS):
        raise DatasetError(f"channel must be [{S}, {A}, 16], got {np.shape(channel)}")
    meta = dict(meta or {})
    extra = {k: v for k, v in meta.items() if k not in
             ("task", "frequency_hz", "fixed_pos", "person_positions", "num_antenna_positions", "num_states")}
    full = base_meta(task=meta.get("task", "rx"), frequency_hz=meta.get("frequency_hz", 2.4e9), num_antennas=A,
                     person_positions=person_pos[1:], fixed_pos=meta.get("fixed_pos", [0.0, 0.0, 0.0]),
                     extra={"source": "write_dataset", **extra})
    split = split if split is not None else make_split(A, S - 1, seed=seed)
    root = prepare_folder(path, full, antenna_pos=antenna_pos, split=split)
    for s in range(S):
        write_chunk(root, s, pas=pas[s], channel=None if channel is None else channel[s])
    return Dataset(root)


def resolve_scene(scene: str | Path) -> Path:
    """A built-in scene name (``bedroom``...) or an XML path -> the XML path (SceneError if missing)."""

    p = Path(scene)
    if p.suffix.lower() == ".xml":
        if not p.is_file():
            raise SceneError(f"scene file {p} does not exist")
        return p.resolve()
    from .. import scenes

    return scenes.path(str(scene))


def _scene_record(xml: Path) -> dict:
    meshes = sorted(xml.parent.rglob("*.ply"))
    h = hashlib.sha256()
    for m in meshes:
        h.update(m.relative_to(xml.parent).as_posix().encode())
        h.update(_sha256(m).encode())
    return {"name": xml.stem, "file": str(xml), "sha256": _sha256(xml),
            "meshes_sha256": h.hexdigest(), "num_meshes": len(meshes)}
