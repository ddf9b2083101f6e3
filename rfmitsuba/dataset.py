"""The on-disk PAS dataset: folder layout, atomic per-state chunks, splits.

Layout of one dataset folder (format ``rfmitsuba-dataset/1``)::

    meta.json          configuration, reproducibility record, units
    split.json         antenna / human train-test indices and their seed
    antenna_pos.npy    float32 [A, 3], metres, world frame
    chunks/00000/      state 0: the empty room
        pas.npy        float32 [A, 90, 360], raw linear Bartlett amplitude
        channel.npy    complex64 [A, 16], narrowband channel per element
        chunk.json     sha256 of both arrays (checked by Dataset.verify)
    chunks/00001/ ...  state s > 0: the human at meta["human_positions"][s-1]

Each chunk folder is written under a temporary name and renamed when
complete, so a folder named ``chunks/<state:05d>`` is either whole or was
damaged afterwards. The flattened SPEC view (``Dataset.arrays``) has row
``k = state * A + antenna``.

Nothing here needs Sionna: :func:`write_dataset` makes small synthetic
datasets for other modules' tests; :mod:`rfmitsuba.simulate` generates real ones.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .atomic import write_json
from .errors import DatasetError, PlacementError

FORMAT = "rfmitsuba-dataset/1"
PAS_SHAPE = (90, 360)
NUM_ELEMENTS = 16
#: Fractions of held-out antenna and human positions (SPEC "Splits").
ANTENNA_TEST_FRACTION = 0.2
HUMAN_TEST_FRACTION = 0.19

UNITS = {
    "positions": "metres, world frame (scene XML), z up",
    "angles": "radians unless the key ends in _deg",
    "frequency_hz": "hertz",
    "pas": "linear Bartlett amplitude |sum_m conj(a_m) h_m| / 16, raw (not normalised)",
    "channel": "complex baseband narrowband channel per element, unitless (sqrt of path gain)",
}


@dataclass(frozen=True)
class Split:
    """Train/test indices (int64, sorted): antenna ones index [0, A), human ones index [0, H).

    Human index ``h`` is dataset state ``h + 1``.
    """

    antenna_train: np.ndarray
    antenna_test: np.ndarray
    human_train: np.ndarray
    human_test: np.ndarray
    seed: int = 0

    def to_json(self) -> dict:
        return {
            "seed": int(self.seed),
            "antenna_test_fraction": ANTENNA_TEST_FRACTION,
            "human_test_fraction": HUMAN_TEST_FRACTION,
            "antenna_train": [int(i) for i in self.antenna_train],
            "antenna_test": [int(i) for i in self.antenna_test],
            "human_train": [int(i) for i in self.human_train],
            "human_test": [int(i) for i in self.human_test],
        }

    @classmethod
    def from_json(cls, d: dict, *, num_antennas: int, num_humans: int, where: str = "split.json") -> "Split":
        try:
            arrs = {k: np.asarray(d[k], dtype=np.int64) for k in
                    ("antenna_train", "antenna_test", "human_train", "human_test")}
            seed = int(d.get("seed", 0))
        except (KeyError, TypeError, ValueError) as e:
            raise DatasetError(f"{where}: missing or malformed key {e}") from None
        for key, n in (("antenna", num_antennas), ("human", num_humans)):
            both = np.concatenate([arrs[f"{key}_train"], arrs[f"{key}_test"]])
            if both.size and (both.min() < 0 or both.max() >= n):
                raise DatasetError(f"{where}: {key} indices outside [0, {n})")
            if len(np.unique(both)) != both.size:
                raise DatasetError(f"{where}: {key} train and test indices overlap or repeat")
        return cls(**arrs, seed=seed)


def make_split(num_antennas: int, num_humans: int, *, seed: int = 0) -> Split:
    """Seeded split per SPEC: 20% of antenna positions and ~19% of human positions held out.

    Args:
        num_antennas: A, number of antenna positions.
        num_humans: H, number of human positions (states minus the empty one).
        seed: RNG seed.
    """
    rng = np.random.default_rng(seed)
    perm_a = rng.permutation(num_antennas)
    n_at = int(round(ANTENNA_TEST_FRACTION * num_antennas)) if num_antennas > 1 else 0
    perm_h = rng.permutation(num_humans)
    n_ht = int(round(HUMAN_TEST_FRACTION * num_humans)) if num_humans > 1 else 0
    return Split(antenna_train=np.sort(perm_a[n_at:]).astype(np.int64),
                 antenna_test=np.sort(perm_a[:n_at]).astype(np.int64),
                 human_train=np.sort(perm_h[n_ht:]).astype(np.int64),
                 human_test=np.sort(perm_h[:n_ht]).astype(np.int64), seed=seed)


# ----------------------------------------------------------------------------- files

def chunk_name(state: int) -> str:
    """Folder name of one state's chunk, e.g. ``00003``."""
    return f"{int(state):05d}"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 22), b""):
            h.update(block)
    return h.hexdigest()


def _write_json(path: Path, obj: Any) -> None:
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


def write_chunk(root: str | Path, state: int, *, pas: np.ndarray, channel: np.ndarray | None = None) -> Path:
    """Write one state's arrays atomically (temporary folder, then rename).

    Args:
        root: dataset folder.
        state: state index s (0 = empty room).
        pas: float32 [A, 90, 360], raw linear amplitude.
        channel: complex64 [A, 16] or None (zeros are stored then).
    Returns:
        The chunk folder. An existing chunk of that state is replaced.
    """
    root = Path(root)
    pas = np.ascontiguousarray(pas, dtype=np.float32)
    if pas.ndim != 3 or pas.shape[1:] != PAS_SHAPE:
        raise DatasetError(f"state {state}: pas must be [A, 90, 360], got {pas.shape}")
    if channel is None:
        channel = np.zeros((pas.shape[0], NUM_ELEMENTS), np.complex64)
    channel = np.ascontiguousarray(channel, dtype=np.complex64)
    if channel.shape != (pas.shape[0], NUM_ELEMENTS):
        raise DatasetError(f"state {state}: channel must be [{pas.shape[0]}, 16], got {channel.shape}")
    chunks = root / "chunks"
    chunks.mkdir(parents=True, exist_ok=True)
    final = chunks / chunk_name(state)
    tmp = chunks / f".tmp-{chunk_name(state)}-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    np.save(tmp / "pas.npy", pas, allow_pickle=False)
    np.save(tmp / "channel.npy", channel, allow_pickle=False)
    _write_json(tmp / "chunk.json", {"state": int(state), "num_antennas": int(pas.shape[0]),
                                     "sha256": {"pas.npy": _sha256(tmp / "pas.npy"),
                                                "channel.npy": _sha256(tmp / "channel.npy")}})
    for f in tmp.iterdir():  # data on disk before the rename makes the chunk visible
        with open(f, "rb") as fh:
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


# ----------------------------------------------------------------------------- reading

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
        human_pos: float32 [S, 3], metres (row 0 NaN: empty room).
        fixed_pos: float64 [3], metres, the fixed device in the room corner.
        split: the saved :class:`Split`.
    """

    def __init__(self, path: str | Path, *, check: bool = True):
        self.path = Path(path)
        meta_file = self.path / "meta.json"
        if not meta_file.is_file():
            raise DatasetError(f"{self.path}: no meta.json, not a dataset folder")
        try:
            self.meta = json.loads(meta_file.read_text())
        except ValueError as e:
            raise DatasetError(f"{meta_file}: not valid JSON ({e})") from None
        if self.meta.get("format") != FORMAT:
            raise DatasetError(f"{meta_file}: format is {self.meta.get('format')!r}, expected {FORMAT!r}")
        for key in ("task", "frequency_hz", "num_antenna_positions", "human_positions", "fixed_pos"):
            if key not in self.meta:
                raise DatasetError(f"{meta_file}: missing key {key!r}")
        self.task = self.meta["task"]
        self.frequency_hz = float(self.meta["frequency_hz"])
        self.num_antennas = int(self.meta["num_antenna_positions"])
        hp = np.asarray(self.meta["human_positions"], dtype=np.float32).reshape(-1, 3)
        self.num_states = 1 + hp.shape[0]
        self.human_pos = np.concatenate([np.full((1, 3), np.nan, np.float32), hp])
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
        self.split = Split.from_json(sd, num_antennas=self.num_antennas, num_humans=self.num_states - 1,
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
        """Flat SPEC arrays, row ``k = state * A + antenna`` (over ``states`` in the given order).

        Returns:
            ``pas`` float32 [K, 90, 360], ``antenna_pos`` float32 [K, 3],
            ``human_pos`` float32 [K, 3] (NaN rows for the empty room),
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
            "human_pos": np.repeat(self.human_pos[states], A, axis=0),
            "state": np.repeat(np.asarray(states, np.int64), A),
            "antenna": np.tile(np.arange(A, dtype=np.int64), len(states)),
        }


def open_dataset(path: str | Path, *, check: bool = True) -> Dataset:
    """Open a dataset folder; DatasetError naming the file/chunk when it is incomplete or damaged.

    A NeRF2 spectrum folder (``spectrum/`` + ``gateway_info.yml``) is read through
    :func:`rfmitsuba.nerf2.read` instead.
    """
    p = Path(path)
    if not (p / "meta.json").exists() and (p / "spectrum").is_dir():
        from . import nerf2

        return nerf2.read(p)
    return Dataset(p, check=check)


# ----------------------------------------------------------------------------- writing

#: keys compared first, so the reported difference is the cause rather than a consequence
_DIFF_FIRST = ("format", "task", "scene", "frequency_hz", "generate", "solver", "seeds", "num_antenna_positions",
               "num_states", "versions")


def config_diff(a: Any, b: Any, prefix: str = "") -> str | None:
    """Dotted name of the first key where two meta dicts differ, or None when equal."""
    if isinstance(a, dict) and isinstance(b, dict):
        keys = sorted(set(a) | set(b))
        keys = [k for k in _DIFF_FIRST if k in keys] + [k for k in keys if k not in _DIFF_FIRST]
        for k in keys:
            if k not in a or k not in b:
                return f"{prefix}{k}"
            d = config_diff(a[k], b[k], f"{prefix}{k}.")
            if d is not None:
                return d
        return None
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return prefix.rstrip(".") or "<root>"
        for i, (x, y) in enumerate(zip(a, b)):
            d = config_diff(x, y, f"{prefix.rstrip('.')}[{i}].")
            if d is not None:
                return d.rstrip(".") if d.endswith(".") else d
        return None
    if a != b:
        return prefix.rstrip(".") or "<root>"
    return None


def prepare_folder(path: str | Path, meta: dict, *, antenna_pos: np.ndarray, split: Split) -> Path:
    """Create the dataset folder (meta, split, antenna positions), or check an existing one matches.

    An existing ``meta.json`` of another configuration raises DatasetError naming
    the first differing key; nothing is overwritten then. A folder holding
    other files but no ``meta.json`` is refused too.
    """
    root = Path(path)
    meta = _jsonable(meta)
    meta_file = root / "meta.json"
    if meta_file.exists():
        try:
            old = json.loads(meta_file.read_text())
        except ValueError as e:
            raise DatasetError(f"{meta_file}: not valid JSON ({e}); refusing to overwrite") from None
        key = config_diff(old, meta)
        if key is not None:
            raise DatasetError(f"{root} holds a dataset of another configuration: key {key!r} differs; "
                               "nothing was overwritten (choose another --out)")
        ap_old = np.load(root / "antenna_pos.npy", allow_pickle=False)
        if not np.array_equal(ap_old, np.asarray(antenna_pos, np.float32)):
            raise DatasetError(f"{root}/antenna_pos.npy differs from this configuration's positions")
        return root
    if root.exists() and any(root.iterdir()):
        raise DatasetError(f"{root} is not empty and holds no dataset; refusing to write into it")
    root.mkdir(parents=True, exist_ok=True)
    np.save(root / "antenna_pos.npy", np.asarray(antenna_pos, np.float32), allow_pickle=False)
    _write_json(root / "split.json", split.to_json())
    _write_json(meta_file, meta)  # last: its presence marks a prepared folder
    return root


def base_meta(*, task: str, frequency_hz: float, num_antennas: int, human_positions: np.ndarray,
              fixed_pos: np.ndarray, extra: dict | None = None) -> dict:
    """The meta.json keys every dataset has, plus ``extra`` (scene, solver, seeds, versions...)."""
    from . import antenna

    if task not in ("rx", "tx"):
        raise DatasetError(f"task must be 'rx' or 'tx', got {task!r}")
    hp = np.asarray(human_positions, np.float64).reshape(-1, 3)
    meta = {
        "format": FORMAT,
        "task": task,
        "frequency_hz": float(frequency_hz),
        "num_antenna_positions": int(num_antennas),
        "num_states": int(1 + hp.shape[0]),
        "human_positions": hp.tolist(),
        "fixed_pos": [float(x) for x in np.asarray(fixed_pos, np.float64).reshape(3)],
        "array": antenna.describe(float(frequency_hz)),
        "pas_layout": {"shape": list(PAS_SHAPE), "row": "elevation (i + 1) deg above the array plane",
                       "column": "azimuth j deg from array +x towards +y"},
        "units": UNITS,
    }
    meta.update(extra or {})
    return _jsonable(meta)


def write_dataset(path: str | Path, *, pas: np.ndarray, antenna_pos: np.ndarray, human_pos: np.ndarray,
                  meta: dict | None = None, split: Split | None = None, seed: int = 0,
                  channel: np.ndarray | None = None) -> Dataset:
    """Write a whole in-memory dataset (tests, converters); needs no Sionna.

    Args:
        path: new (or empty) folder.
        pas: float32 [S, A, 90, 360], raw or normalised amplitude.
        antenna_pos: float [A, 3], metres.
        human_pos: float [S, 3], metres; row 0 must be NaN (the empty room).
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
    human_pos = np.asarray(human_pos, np.float64)
    if human_pos.shape != (S, 3):
        raise DatasetError(f"human_pos must be [{S}, 3], got {human_pos.shape}")
    if not np.isnan(human_pos[0]).all() or not np.isfinite(human_pos[1:]).all():
        raise DatasetError("human_pos row 0 must be NaN (empty room) and rows 1.. finite")
    if channel is not None and np.shape(channel) != (S, A, NUM_ELEMENTS):
        raise DatasetError(f"channel must be [{S}, {A}, 16], got {np.shape(channel)}")
    meta = dict(meta or {})
    extra = {k: v for k, v in meta.items() if k not in
             ("task", "frequency_hz", "fixed_pos", "human_positions", "num_antenna_positions", "num_states")}
    full = base_meta(task=meta.get("task", "rx"), frequency_hz=meta.get("frequency_hz", 2.4e9), num_antennas=A,
                     human_positions=human_pos[1:], fixed_pos=meta.get("fixed_pos", [0.0, 0.0, 0.0]),
                     extra={"source": "write_dataset", **extra})
    split = split if split is not None else make_split(A, S - 1, seed=seed)
    root = prepare_folder(path, full, antenna_pos=antenna_pos, split=split)
    for s in range(S):
        write_chunk(root, s, pas=pas[s], channel=None if channel is None else channel[s])
    return Dataset(root)


# ----------------------------------------------------------------------------- generation

@dataclass
class GenerateConfig:
    """What :func:`generate` simulates (every field is recorded in meta.json).

    Heights (``z_range``, ``corner_height``) are metres above the floor.
    """

    scene: str = "bedroom"
    task: str = "rx"
    positions: int = 900
    human_positions: int = 35
    material: str = "tissue"
    seed: int = 0
    frequency_hz: float = 2.4e9
    z_range: tuple[float, float] = (0.5, 2.0)
    #: distance of antenna positions to walls and furniture, metres
    clearance: float = 0.15
    #: extra horizontal distance of antenna positions (below head height) to every walk position, metres
    human_margin: float = 0.15
    corner_inset: float = 0.3
    corner_height: float = 2.0
    walk_duration_s: float = 60.0
    #: material scattering coefficient set after loading when diffuse reflection is on
    scattering_coefficient: float = 0.3
    solver: "Any" = None  # simulate.SolverConfig; None -> defaults for the room size


QUICK = {"positions": 36, "human_positions": 4, "samples_per_src": 20_000}


def quick_config(scene: str = "bedroom", **overrides) -> GenerateConfig:
    """The ``--quick`` configuration: 36 positions x (1 + 4) states at 2e4 samples per source."""
    from .simulate import SolverConfig

    # the walk keeps the full walk's step (60 s / 35 positions), so its straight steps stay short
    kw = {"scene": scene, "positions": QUICK["positions"], "human_positions": QUICK["human_positions"],
          "walk_duration_s": 60.0 * QUICK["human_positions"] / 35,
          "solver": SolverConfig(samples_per_src=QUICK["samples_per_src"])}
    kw.update(overrides)
    return GenerateConfig(**kw)


def resolve_scene(scene: str | Path) -> Path:
    """A built-in scene name (``bedroom``...) or an XML path -> the XML path (SceneError if missing)."""
    from .errors import SceneError

    p = Path(scene)
    if p.suffix.lower() == ".xml":
        if not p.is_file():
            raise SceneError(f"scene file {p} does not exist")
        return p.resolve()
    from . import scenes

    return scenes.path(str(scene))


def _scene_record(xml: Path) -> dict:
    meshes = sorted(xml.parent.rglob("*.ply"))
    h = hashlib.sha256()
    for m in meshes:
        h.update(m.relative_to(xml.parent).as_posix().encode())
        h.update(_sha256(m).encode())
    return {"name": xml.stem, "file": str(xml), "sha256": _sha256(xml),
            "meshes_sha256": h.hexdigest(), "num_meshes": len(meshes)}


def place_antennas(geometry, n: int, *, rng: np.random.Generator, z_range: tuple[float, float],
                   clearance: float, walk_positions: np.ndarray, body_radius: float, body_height: float,
                   avoid: np.ndarray | None = None) -> np.ndarray:
    """``n`` antenna positions in the free volume, float64 [n, 3], metres.

    Never inside furniture (``clearance`` from walls and furniture), never inside the
    human at any walk position (horizontal distance > ``body_radius`` unless above
    ``body_height``), and at least 0.3 m from ``avoid`` (the fixed device, float [3]).
    """
    out: list[np.ndarray] = []
    got = 0
    walk_xy = np.asarray(walk_positions, np.float64).reshape(-1, 3)
    for _ in range(100):
        c = geometry.sample_free(max(64, 2 * n), rng=rng, z_range=z_range, clearance=clearance)
        ok = np.ones(len(c), bool)
        if len(walk_xy):
            dxy = np.linalg.norm(c[:, None, :2] - walk_xy[None, :, :2], axis=-1)
            below = c[:, None, 2] < walk_xy[None, :, 2] + body_height
            ok &= ~np.any((dxy < body_radius) & below, axis=1)
        if avoid is not None:
            ok &= np.linalg.norm(c - np.asarray(avoid, np.float64), axis=1) > 0.3
        out.append(c[ok])
        got += int(ok.sum())
        if got >= n:
            break
    if got < n:
        raise PlacementError(f"found only {got} of {n} antenna positions clear of furniture and the walk")
    return np.concatenate(out)[:n]


def default_solver(geometry, *, quick: bool = False):
    """SolverConfig for a room: 1e5 samples per source, 3e5 for rooms over 50 m^2 floor (SPEC facts)."""
    from .simulate import SolverConfig

    area = float(np.prod(geometry.size[:2]))
    samples = 300_000 if area > 50 else 100_000
    if quick:
        samples = QUICK["samples_per_src"]
    return SolverConfig(samples_per_src=samples)


def generate(out: str | Path, cfg: GenerateConfig, *, repair: bool = False, quiet: bool = False,
             stop_after: int | None = None) -> Dataset:
    """Simulate a dataset into folder ``out``, resuming from the first missing chunk.

    Args:
        out: dataset folder (created; an existing one must hold the same configuration).
        cfg: :class:`GenerateConfig`.
        repair: re-simulate chunks that fail the full (sha256) check instead of raising.
        quiet: no progress bar.
        stop_after: simulate at most this many states, then return (for tests of resuming).
    Returns:
        The dataset, opened (only if complete; else the partially written one unchecked).
    Raises:
        DatasetError: ``out`` holds another configuration (the differing key is named) or a
            damaged chunk (named) and ``repair`` is off.
        PlacementError: bad positions; SceneError: unknown or broken scene.
    """
    import time

    from . import human, progress
    from .geometry import RoomGeometry
    from .simulate import Simulator, SolverConfig, versions

    from . import config as _config
    from .errors import ConfigError

    if cfg.task not in ("rx", "tx"):
        raise ConfigError(f"task must be 'rx' or 'tx', got {cfg.task!r}")
    if cfg.positions < 1 or cfg.human_positions < 0:
        raise ConfigError(f"need positions >= 1 and human_positions >= 0, got {cfg.positions}, {cfg.human_positions}")
    if cfg.material not in human.PERTURBER_MATERIALS:
        raise ConfigError(f"unknown material {cfg.material!r}; known: {', '.join(human.PERTURBER_MATERIALS)}")
    t_start = time.perf_counter()
    xml = resolve_scene(cfg.scene)
    geom = RoomGeometry.from_xml(xml)
    solver = cfg.solver if cfg.solver is not None else default_solver(geom)
    if isinstance(solver, dict):
        solver = _config.from_dict(SolverConfig, solver)
    solver.check()
    fixed = geom.corner(inset=cfg.corner_inset, height=cfg.corner_height)
    if cfg.human_positions:
        walk = human.walk(geom, n=cfg.human_positions, duration_s=cfg.walk_duration_s, seed=cfg.seed)
        walk_pos, walk_head = np.asarray(walk.positions), np.asarray(walk.headings)
    else:
        walk_pos, walk_head = np.zeros((0, 3)), np.zeros(0)
    body_r = human.radius() + cfg.human_margin
    ant = place_antennas(geom, cfg.positions, rng=np.random.default_rng([cfg.seed, 1]), z_range=cfg.z_range,
                         clearance=cfg.clearance, walk_positions=walk_pos, body_radius=body_r,
                         body_height=human.HEIGHT + 0.1, avoid=fixed)
    geom.check_points(ant, what="antenna")
    ant32 = ant.astype(np.float32)
    plugin, params = human.PERTURBER_MATERIALS[cfg.material]
    extra = {
        "scene": _scene_record(xml),
        "generate": {k: v for k, v in _config.to_dict(_replace(cfg, solver=None)).items() if k != "solver"},
        "solver": _config.to_dict(solver),
        "seeds": {"antenna_positions": [cfg.seed, 1], "walk": cfg.seed, "split": cfg.seed, "solver": solver.seed},
        "human": {"headings_rad": walk_head.tolist(), "height_m": human.HEIGHT, "width_m": human.WIDTH,
                  "material": cfg.material, "material_plugin": plugin, "material_params": params,
                  "placement": "feet at human_positions, facing headings_rad (about +z)"},
        "fixed_device": "isotropic TX" if cfg.task == "rx" else "4x4 array",
        "moving_device": "4x4 array" if cfg.task == "rx" else "isotropic TX",
        "reciprocity": "one solve: TX at fixed_pos, isotropic RX at each antenna position; "
                       + ("arrival directions at the antenna positions" if cfg.task == "rx" else
                          "departure directions at fixed_pos") + " give the array channel",
        "versions": versions(),
    }
    meta = base_meta(task=cfg.task, frequency_hz=cfg.frequency_hz, num_antennas=cfg.positions,
                     human_positions=walk_pos, fixed_pos=fixed, extra=extra)
    split = make_split(cfg.positions, cfg.human_positions, seed=cfg.seed)
    root = prepare_folder(out, meta, antenna_pos=ant32, split=split)
    remove_stale_tmp(root)
    S = 1 + cfg.human_positions
    todo = []
    for s in range(S):
        if not (root / "chunks" / chunk_name(s)).exists():
            todo.append(s)
            continue
        try:
            check_chunk(root, s, cfg.positions, full=repair)
        except DatasetError as e:
            if not repair:
                raise DatasetError(f"{e}; run generate with --repair to simulate it again") from None
            todo.append(s)
    if stop_after is not None:
        todo = todo[:stop_after]
    timing = {"states": len(todo), "solver_s": 0.0, "pas_s": 0.0, "write_s": 0.0}
    if todo:
        sim = Simulator(xml, fixed_pos=fixed, frequency_hz=cfg.frequency_hz, solver=solver)
        if solver.diffuse_reflection:
            sim.set_scattering(cfg.scattering_coefficient)
        # positions as float32, the precision they are stored with
        sim.set_positions(ant32.astype(np.float64))
        faces = None
        with progress.bar(len(todo), desc=f"{xml.stem} {cfg.task}", unit="state", quiet=quiet) as pb:
            for s in todo:
                if s == 0:
                    sim.set_human(None)
                else:
                    mesh = human.human_mesh(walk_pos[s - 1], float(walk_head[s - 1]))
                    if faces is None:
                        faces = np.asarray(human.human_mesh(walk_pos[0], float(walk_head[0])).faces)
                        first = np.asarray(human.human_mesh(walk_pos[0], float(walk_head[0])).vertices)
                        sim.set_human(first, faces, material=human.radio_material(cfg.material,
                                                                                  name=f"rfm-human-{cfg.material}"))
                    sim.set_human(np.asarray(mesh.vertices))
                t0 = sim.timing.solver_s
                paths = sim.solve()
                timing["solver_s"] += sim.timing.solver_s - t0
                t1 = time.perf_counter()
                from . import pas as _pas

                h = paths.channels(cfg.task, frequency_hz=cfg.frequency_hz)
                img = _pas.bartlett(h, frequency_hz=cfg.frequency_hz)
                t2 = time.perf_counter()
                write_chunk(root, s, pas=img, channel=h)
                timing["write_s"] += time.perf_counter() - t2
                timing["pas_s"] += t2 - t1
                pb.update(1)
    timing["total_s"] = time.perf_counter() - t_start
    timing["outside_solver_share"] = 1 - timing["solver_s"] / timing["total_s"] if timing["total_s"] else 0.0
    _append_timing(root, timing)
    missing = [s for s in range(S) if not (root / "chunks" / chunk_name(s)).exists()]
    return Dataset(root, check=not missing)


def _replace(cfg, **kw):
    import dataclasses

    return dataclasses.replace(cfg, **kw)


def _append_timing(root: Path, timing: dict) -> None:
    f = root / "timing.json"
    runs = []
    if f.exists():
        try:
            runs = json.loads(f.read_text())
        except ValueError:
            runs = []
    runs.append(timing)
    _write_json(f, runs)
