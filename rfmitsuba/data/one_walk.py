"""The One Walk dataset layout (read and write): a static folder (the empty room) and a dynamic
folder (a person walking through it), as the One Walk code's loader reads them.

A static folder::

    spectrum/00001.png ...   90 x 360 8-bit greyscale, min-max normalised PAS (row = elevation
                             1..90 deg, column = azimuth 0..359 deg, PAS layout, docs/conventions.md),
                             numbered from 1
    rx_info.csv              header ``x,y,z`` (other columns are ignored), then one row per image
                             (image n -> row n) [m]: the moving device. ``rx_pos.csv`` is read
                             where there is no ``rx_info.csv``
    gateway_info.yml         the fixed device: ``gateway1: {position: [x, y, z], orientation: [x, y, z, w]}``
    train_index.txt          image names (``00001``), 1-based, one per line
    test_index.txt

A dynamic folder::

    spectrums/00001.png ...  as ``spectrum/``
    spectrum_info.csv        header ``index,rx_x,rx_y,rx_z,man_x,man_y,man_z,qx,qy,qz,qw,frame_idx``,
                             one row per image: its number (``index``: ``spectrums/00007.png`` is
                             index 7), the moving device [m], the person's position [m] and
                             orientation (quaternion x, y, z, w: body -> world), and the frame of
                             the walk (an integer, one per pose of the person)
    train_index.txt          image names: training positions x training frames
    val_index.txt            the mixed pairs: training positions x test frames, test x training
    test_index.txt           test positions x test frames

Either may hold ``rfmitsuba.json`` (written here; the One Walk loader ignores it) with what the
layout leaves unstated: :class:`OneWalkConfig`'s keys, the source dataset and its scene.

As a dataset (:class:`OneWalkDataset`, the :class:`rfmitsuba.data.store.Dataset` interface):
state 0 is the static folder, states 1..H are the dynamic folder's frames in ``frame_idx``
order, and the antenna positions are the static folder's rows. Every frame must hold one
spectrum at each static position (within ``position_tolerance_m``). The antenna split is the
static folder's index files; the person split is the frames of the dynamic ``train_index.txt``
(training) and ``test_index.txt`` (test). A folder without ``rfmitsuba.json`` is read as the
One Walk code trains on it: moving RX (``task = "rx"``), the gateway the fixed transmitter, the
array frame the world frame.
"""
from __future__ import annotations

import json
import math
import re
import warnings
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from ..core.errors import DatasetError
from ..rf.grid import PAS_SHAPE
from .nerf2 import (EXTRA, _numbers, _read_gateway, _read_index, _read_text, _write_gateway, quaternion_matrix,
                    read_image, read_positions, to_uint8, write_positions)
from .split import Split, make_split

FORMAT = "rfmitsuba-one-walk/1"
#: carrier where neither the reader nor the folder says (the project's default carrier), Hz
DEFAULT_FREQUENCY_HZ = 2.4e9
#: how far a dynamic row's moving device may lie from a static position and still be it [m]
DEFAULT_TOLERANCE_M = 1e-3
#: names of the static and the dynamic folder beside each other (ours, then the One Walk code's)
STATIC_NAMES = ("static", "static_dataset")
DYNAMIC_NAMES = ("dynamic", "dynamic_dataset")
#: the static folder's positions file (the One Walk code's, then its README's name)
POSITION_FILES = ("rx_info.csv", "rx_pos.csv")
INFO = "spectrum_info.csv"
INFO_COLUMNS = ("index", "rx_x", "rx_y", "rx_z", "man_x", "man_y", "man_z", "qx", "qy", "qz", "qw", "frame_idx")
_REQUIRED = INFO_COLUMNS[:7]
_QUAT = ("qx", "qy", "qz", "qw")
_IDENTITY = (0.0, 0.0, 0.0, 1.0)
#: an image number as the index files and ``index`` write it: ASCII digits
_INT = re.compile(r"[+-]?[0-9]+", re.ASCII)
_FLOAT = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?", re.ASCII)


@dataclass(frozen=True, kw_only=True)
class OneWalkConfig:
    """What the layout leaves unstated. ``None`` takes the folder's ``rfmitsuba.json``, else the
    default named here; a value given here overrides the folder.

    Attributes:
        frequency_hz: carrier [Hz]; default :data:`DEFAULT_FREQUENCY_HZ` (2.4 GHz).
        fixed_pos: the fixed device [m], (x, y, z); default ``gateway1.position`` of the static
            folder's ``gateway_info.yml`` (then ``rfmitsuba.json``); a folder with neither is refused.
        array_orientation: the array frame (quaternion x, y, z, w: array -> world); default the
            identity, as the One Walk code trains.
        task: ``"rx"`` (the moving device is the receiving array; default) or ``"tx"`` (it is the
            transmitter, the fixed device the array).
        readout: ``"amplitude"`` (default) or ``"phase_only"``: how the spectra were read out.
        static: the static folder of a dynamic one (absolute, or relative to the dynamic folder);
            default a sibling ``static/`` or ``static_dataset/``.
        position_tolerance_m: how close a dynamic row's moving device must be to a static
            position [m]; default :data:`DEFAULT_TOLERANCE_M` (1 mm).
    """

    frequency_hz: float | None = None
    fixed_pos: tuple[float, float, float] | None = None
    array_orientation: tuple[float, float, float, float] | None = None
    task: str | None = None
    readout: str | None = None
    static: str | None = None
    position_tolerance_m: float | None = None


_KEYS = tuple(f.name for f in fields(OneWalkConfig))


def _checked(key: str, value, where: str):
    """``value`` of option ``key`` in its type, or DatasetError naming ``where`` and the option."""
    if key in ("frequency_hz", "position_tolerance_m"):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            raise DatasetError(f"{where}: {key} must be a positive number, got {value!r}")
        return float(value)
    if key == "fixed_pos":
        v = _numbers(list(value) if isinstance(value, (list, tuple, np.ndarray)) else value, 3)
        if v is None:
            raise DatasetError(f"{where}: fixed_pos must be [x, y, z] (finite numbers, metres), got {value!r}")
        return v
    if key == "array_orientation":
        v = _numbers(list(value) if isinstance(value, (list, tuple, np.ndarray)) else value, 4)
        if v is None or not 1e-9 < np.linalg.norm(v) < np.inf:
            raise DatasetError(f"{where}: array_orientation must be a non-zero quaternion [x, y, z, w], got {value!r}")
        return v
    choices = {"task": ("rx", "tx"), "readout": ("amplitude", "phase_only")}.get(key)
    if choices is not None:
        if value not in choices:
            raise DatasetError(f"{where}: {key} must be {' or '.join(map(repr, choices))}, got {value!r}")
        return value
    if not isinstance(value, str) or not value:
        raise DatasetError(f"{where}: {key} must be a folder name, got {value!r}")
    return value


def _read_extra(folder: Path) -> dict:
    """The options of ``folder/rfmitsuba.json`` ({} when absent), checked; the file's other keys
    under ``"_file"`` and its path under ``"_where"``."""
    f = folder / EXTRA
    if not f.is_file():
        return {}
    try:
        doc = json.loads(_read_text(f))
    except json.JSONDecodeError as e:
        raise DatasetError(f"{f}:{e.lineno}: not valid JSON ({e.msg})") from None
    if not isinstance(doc, dict):
        raise DatasetError(f"{f}: expected a JSON object, got {type(doc).__name__}")
    out = {k: _checked(k, doc[k], str(f)) for k in _KEYS if doc.get(k) is not None}
    out["_file"], out["_where"] = doc, f
    return out


def layout(path: str | Path) -> str | None:
    """Which One Walk folder ``path`` is: ``"static"`` (``spectrum/`` and ``rx_info.csv`` or
    ``rx_pos.csv``, no NeRF2 ``tx_pos.csv``), ``"dynamic"`` (``spectrums/`` or
    ``spectrum_info.csv``), ``"pair"`` (a ``static/`` or ``dynamic/`` folder, or the One Walk code's
    ``static_dataset/`` / ``dynamic_dataset/``, inside it) or None."""
    p = Path(path)
    if (p / "spectrum").is_dir() and any((p / n).is_file() for n in POSITION_FILES) and not (p / "tx_pos.csv").exists():
        return "static"
    if (p / "spectrums").is_dir() or (p / INFO).is_file():
        return "dynamic"
    if any((p / n / "spectrum").is_dir() for n in STATIC_NAMES) or \
            any((p / n / "spectrums").is_dir() or (p / n / INFO).is_file() for n in DYNAMIC_NAMES):
        return "pair"
    return None


def _image_files(folder: Path) -> dict[int, Path]:
    """{image number: file} of the PNG images in ``folder`` (names like ``00001.png``)."""
    if not folder.is_dir():
        raise DatasetError(f"{folder} is missing (the spectrum images)")
    out: dict[int, Path] = {}
    for f in sorted(folder.glob("*.png")):
        if not (f.stem.isascii() and f.stem.isdigit()):
            raise DatasetError(f"{f}: image names must be 1-based numbers like 00001.png")
        n = int(f.stem)
        if n in out:
            raise DatasetError(f"{folder}: image number {n} appears twice ({out[n].name} and {f.name})")
        out[n] = f
    if not out:
        raise DatasetError(f"{folder}: no PNG images")
    return out


def _read_info(path: Path) -> dict[str, np.ndarray]:
    """The columns of ``spectrum_info.csv``: ``index`` and ``frame_idx`` int64 [N], the others
    float64 [N] (``qx``..``qw`` and ``frame_idx`` only where the header has them), ``line`` int64 [N]."""
    lines = [(n, ln) for n, ln in enumerate(_read_text(path).splitlines(), 1) if ln.strip()]
    if not lines:
        raise DatasetError(f"{path}: empty, expected a header ({','.join(INFO_COLUMNS)}) and one row per image")
    head = [c.strip().strip('"').strip().lower() for c in lines[0][1].split(",")]
    missing = [c for c in _REQUIRED if c not in head]
    if missing:
        raise DatasetError(f"{path}: no column {', '.join(map(repr, missing))} (the header is {lines[0][1][:120]!r})")
    quat = [c for c in _QUAT if c in head]
    if quat and len(quat) < 4:
        raise DatasetError(f"{path}: the person's orientation needs all of qx, qy, qz, qw; the header has only "
                           f"{', '.join(quat)}")
    wanted = [c for c in INFO_COLUMNS if c in head]
    for c in wanted:
        if head.count(c) > 1:
            raise DatasetError(f"{path}: column {c!r} appears {head.count(c)} times in the header")
    if len(lines) < 2:
        raise DatasetError(f"{path}: a header row and no rows")
    cols = {c: [] for c in wanted}
    cols["line"] = []
    for n, s in lines[1:]:
        cells = [c.strip().strip('"').strip() for c in s.split(",")]
        if len(cells) != len(head):
            raise DatasetError(f"{path}:{n}: {len(cells)} cells, the header has {len(head)}")
        for c in wanted:
            cell = cells[head.index(c)]
            if c in ("index", "frame_idx"):
                if not _INT.fullmatch(cell):
                    raise DatasetError(f"{path}:{n}: {c} must be a whole number, got {cell[:40]!r}")
                v = int(cell)
                if abs(v) >= 2 ** 62:
                    raise DatasetError(f"{path}:{n}: {c} {cell[:40]!r} is out of range")
                if c == "index" and v < 1:
                    raise DatasetError(f"{path}:{n}: index must be an image number >= 1, got {v}")
            else:
                v = float(cell) if _FLOAT.fullmatch(cell) else math.nan
                if not math.isfinite(v):
                    raise DatasetError(f"{path}:{n}: {c} is {cell[:40]!r}, not a finite number")
            cols[c].append(v)
        cols["line"].append(n)
    out = {c: np.asarray(v, np.int64 if c in ("index", "frame_idx", "line") else np.float64) for c, v in cols.items()}
    uniq, first, counts = np.unique(out["index"], return_index=True, return_counts=True)
    if (counts > 1).any():
        k = int(np.flatnonzero(counts > 1)[0])
        dup = np.flatnonzero(out["index"] == uniq[k])
        raise DatasetError(f"{path}: index {int(uniq[k])} appears {int(counts[k])} times (lines "
                           f"{', '.join(str(int(out['line'][r])) for r in dup[:3])})")
    if "qx" in out:
        q = np.stack([out[c] for c in _QUAT], 1)
        bad = np.flatnonzero(~(np.linalg.norm(q, axis=1) > 1e-9))
        if bad.size:
            raise DatasetError(f"{path}:{int(out['line'][bad[0]])}: the person's orientation qx, qy, qz, qw is zero")
    return out


def _read_names(path: Path, known: dict[int, int]) -> np.ndarray:
    """Rows (int64 [k], into ``spectrum_info.csv``) of the image names in index file ``path``;
    ``known`` maps an image number to its row."""
    tokens = [t for t in re.split(r"[\s,]+", _read_text(path).strip()) if t]
    bad = next((t for t in tokens if not _INT.fullmatch(t) or t.startswith("-")), None)
    if bad is not None:
        raise DatasetError(f"{path}: entries must be image numbers like 00001, found {bad[:40]!r}")
    rows, seen = [], set()
    for t in tokens:
        n = int(t) if len(t) < 19 else -1
        if n not in known:
            raise DatasetError(f"{path}: image {t[:40]} is not in {INFO}")
        if n in seen:
            raise DatasetError(f"{path}: image {n:05d} appears more than once")
        seen.add(n)
        rows.append(known[n])
    return np.asarray(rows, np.int64)


def matrix_quaternion(r: np.ndarray) -> np.ndarray:
    """The unit quaternion float64 [4] ``[x, y, z, w]`` (w >= 0) of a rotation matrix [3, 3]
    (the inverse of :func:`rfmitsuba.data.nerf2.quaternion_matrix`)."""
    m = np.asarray(r, np.float64).reshape(3, 3)
    t = np.trace(m)
    if t > 0:
        s = 2.0 * math.sqrt(1.0 + t)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + m[i, i] - m[j, j] - m[k, k], 1e-300))
        q = [0.0, 0.0, 0.0, (m[k, j] - m[j, k]) / s]
        q[i], q[j], q[k] = s / 4, (m[j, i] + m[i, j]) / s, (m[k, i] + m[i, k]) / s
    q = np.asarray(q) / np.linalg.norm(q)
    return -q if q[3] < 0 else q


def heading_quaternion(heading_rad: np.ndarray) -> np.ndarray:
    """Quaternions float64 [n, 4] ``[x, y, z, w]`` of turns by ``heading_rad`` (float [n] [rad]) about +z."""
    h = np.asarray(heading_rad, np.float64).reshape(-1)
    return np.stack([np.zeros_like(h), np.zeros_like(h), np.sin(h / 2), np.cos(h / 2)], 1)


def quaternion_heading(q: np.ndarray) -> np.ndarray:
    """Headings float64 [n] [rad] about +z (yaw) of quaternions [n, 4] ``[x, y, z, w]``."""
    x, y, z, w = (np.asarray(q, np.float64).reshape(-1, 4) / np.linalg.norm(np.reshape(q, (-1, 4)), axis=1,
                                                                            keepdims=True)).T
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


class _StateImages:
    """One state's PAS, float32 [A, 90, 360] in [0, 1], held as uint16 (``value * 65535``, exact
    for 8-bit and 16-bit images): indexing converts only the rows asked for."""

    def __init__(self, codes: np.ndarray):
        self._codes = codes
        self.shape = codes.shape
        self.dtype = np.dtype(np.float32)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key) -> np.ndarray:
        return self._codes[key].astype(np.float32) / np.float32(65535.0)

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        out = self[:]
        return out if dtype is None else out.astype(dtype)


class OneWalkDataset:
    """A One Walk static folder, or a static and a dynamic folder, read with the
    :class:`rfmitsuba.data.store.Dataset` interface (see the module docstring).

    Attributes:
        path: the folder given; static_path, dynamic_path (None for a static folder alone).
        task, frequency_hz [Hz], readout: as :class:`OneWalkConfig` resolves them.
        num_antennas: A (the static folder's images); num_states: S = 1 + H.
        antenna_pos: float32 [A, 3] [m], the moving device.
        fixed_pos: float64 [3] [m]; rx_to_world: float64 [3, 3], the array frame.
        person_pos: float32 [S, 3] [m] (row 0 NaN: the empty room); person_orientation: float64
            [S, 4] quaternions ``[x, y, z, w]`` (row 0 NaN); frame_idx: int64 [H], each state's frame.
        split: antenna split of the static index files, person split of the dynamic ones.
        measured: no ``rfmitsuba.json`` in either folder (a folder as published).
        warnings: what was accepted but looks wrong (also warned).
    """

    def __init__(self, path: str | Path, *, config: OneWalkConfig | None = None):
        self.path = Path(path)
        cfg = config or OneWalkConfig()
        given = {k: _checked(k, getattr(cfg, k), "OneWalkConfig") for k in _KEYS if getattr(cfg, k) is not None}
        kind = layout(self.path)
        if kind is None:
            raise DatasetError(f"{self.path}: not a One Walk folder (a static folder holds spectrum/ and rx_info.csv "
                               f"or rx_pos.csv, a dynamic one spectrums/ and {INFO})")
        static = self.path if kind == "static" else None
        dynamic = self.path if kind == "dynamic" else None
        if kind == "pair":
            static = next((self.path / n for n in STATIC_NAMES if (self.path / n).is_dir()), None)
            dynamic = next((self.path / n for n in DYNAMIC_NAMES if (self.path / n).is_dir()), None)
            if static is None:
                raise DatasetError(f"{self.path}: a dynamic folder ({dynamic}) and no static folder (the empty room) "
                                   f"beside it: looked for {', '.join(n + '/' for n in STATIC_NAMES)}")
        dyn_extra = _read_extra(dynamic) if dynamic is not None else {}
        if static is None:
            static = self._find_static(dynamic, given.get("static") or dyn_extra.get("static"))
        st_extra = _read_extra(static)
        s = {**{k: v for k, v in st_extra.items() if not k.startswith("_")},
             **{k: v for k, v in dyn_extra.items() if not k.startswith("_")}, **given}
        self.static_path, self.dynamic_path = static, dynamic
        self.measured = not (st_extra or dyn_extra)
        self.task = s.get("task", "rx")
        self.readout = s.get("readout", "amplitude")
        self.frequency_hz = float(s.get("frequency_hz", DEFAULT_FREQUENCY_HZ))
        tol = float(s.get("position_tolerance_m", DEFAULT_TOLERANCE_M))
        quat = np.asarray(s.get("array_orientation", _IDENTITY), np.float64)
        self.rx_to_world = quaternion_matrix(quat)
        self.warnings: list[str] = []
        self._read_static(static, given, s)
        self._images: dict[int, _StateImages] = {}
        A = self.num_antennas
        H = 0
        person_split = (np.zeros(0, np.int64), np.zeros(0, np.int64))
        if dynamic is not None:
            H, person_split = self._read_dynamic(dynamic, tol)
        self.num_states = 1 + H
        extra = {**st_extra.get("_file", {}), **dyn_extra.get("_file", {})}
        seed = extra.get("split_seed", 0)
        self.split = Split(antenna_train=self._antenna_split[0], antenna_test=self._antenna_split[1],
                           person_train=person_split[0], person_test=person_split[1],
                           seed=seed if isinstance(seed, int) and not isinstance(seed, bool) else 0)
        hum = {"orientation_xyzw": self.person_orientation[1:].tolist(),
               "headings_rad": quaternion_heading(self.person_orientation[1:]).tolist() if H else [],
               "frame_idx": self.frame_idx.tolist()}
        self.meta = {"format": "one-walk", "task": self.task, "frequency_hz": self.frequency_hz,
                     "num_antenna_positions": A, "num_states": self.num_states, "fixed_pos": self.fixed_pos.tolist(),
                     "array_orientation_xyzw": (quat / np.linalg.norm(quat)).tolist(),
                     "person_positions": self.person_pos[1:].astype(np.float64).tolist(), "person": hum,
                     "one_walk": {"static": str(static), "dynamic": None if dynamic is None else str(dynamic),
                                  "extra": extra},
                     "warnings": self.warnings, "readout": self.readout, "measured": self.measured}
        for key in ("scene", "solver"):    # what the source dataset was simulated in (TrainData reads them)
            if key in extra:
                self.meta[key] = extra[key]

    @staticmethod
    def _find_static(dynamic: Path, stated: str | None) -> Path:
        if stated is not None:
            p = Path(stated) if Path(stated).is_absolute() else dynamic / stated
            if not p.is_dir():
                raise DatasetError(f"{dynamic}: the static folder {p} it names does not exist")
            return p
        for n in STATIC_NAMES:
            p = dynamic.parent / n
            if p.is_dir() and p.resolve() != dynamic.resolve():
                return p
        raise DatasetError(f"{dynamic}: no static folder (the empty room) beside it: looked for "
                           f"{', '.join(str(dynamic.parent / n) for n in STATIC_NAMES)}; name one with \"static\" "
                           f"in {dynamic / EXTRA} or OneWalkConfig(static=...)")

    def _read_static(self, static: Path, given: dict, s: dict) -> None:
        spec = static / "spectrum"
        files = _image_files(spec)
        A = len(files)
        if sorted(files) != list(range(1, A + 1)):
            missing = [n for n in range(1, max(files) + 1) if n not in files]
            raise DatasetError(f"{spec}: image {missing[0]:05d}.png is missing"
                               + (f" ({len(missing)} numbers missing in all)" if len(missing) > 1 else "")
                               + f"; images must be numbered 1..{A} without gaps")
        csv = next((static / n for n in POSITION_FILES if (static / n).is_file()), None)
        if csv is None:
            raise DatasetError(f"{static}: no {' or '.join(POSITION_FILES)} (the moving device's positions)")
        pos = read_positions(csv)
        if len(pos) < A:
            raise DatasetError(f"{csv}: {len(pos)} positions for {A} images in spectrum/ (one row per image)")
        if len(pos) > A:
            self._warn(f"{csv}: {len(pos)} positions but only {A} images in spectrum/; images 1..{A} take the first "
                       f"{A} rows (is spectrum/ complete?)")
        self.antenna_pos = pos[:A].astype(np.float32)
        self._static_files = [files[n] for n in range(1, A + 1)]
        self.positions_file = csv
        gw = static / "gateway_info.yml"
        if "fixed_pos" in given:
            self.fixed_pos = np.asarray(given["fixed_pos"], np.float64)
        elif gw.is_file():
            self.fixed_pos = _read_gateway(gw)[0]
        elif "fixed_pos" in s:
            self.fixed_pos = np.asarray(s["fixed_pos"], np.float64)
        else:
            raise DatasetError(f"{static}: the fixed device's position is not stated: no gateway_info.yml "
                               f"(gateway1.position [m]) and no fixed_pos in {static / EXTRA} or OneWalkConfig")
        self.num_antennas = A
        tr, te = static / "train_index.txt", static / "test_index.txt"
        if tr.is_file() and te.is_file():
            train, test = _read_index(tr, A), _read_index(te, A)
            shared = np.intersect1d(train, test)
            if shared.size:
                raise DatasetError(f"{tr} and {te} share images (e.g. {int(shared[0]) + 1:05d})")
        else:
            sp = make_split(A, 0, seed=0)
            train, test = sp.antenna_train, sp.antenna_test
        self._antenna_split = (train, test)
        self.person_pos = np.full((1, 3), np.nan, np.float32)
        self.person_orientation = np.full((1, 4), np.nan)
        self.frame_idx = np.zeros(0, np.int64)

    def _read_dynamic(self, dynamic: Path, tol: float) -> tuple[int, tuple[np.ndarray, np.ndarray]]:
        """Frames, grid of images and person split of the dynamic folder; returns (H, (train, test))."""
        info_path = dynamic / INFO
        info = _read_info(info_path)
        spec = dynamic / "spectrums"
        files = _image_files(spec)
        idx, line = info["index"], info["line"]
        for r in range(len(idx)):
            if int(idx[r]) not in files:
                raise DatasetError(f"{spec}: image {int(idx[r]):05d}.png is missing ({INFO} line {int(line[r])}, "
                                   f"index {int(idx[r])})")
        unused = sorted(set(files) - set(int(i) for i in idx))
        if unused:
            self._warn(f"{spec}: {len(unused)} images have no row in {INFO} (e.g. {files[unused[0]].name}); "
                       "they are not read")
        man = np.stack([info[c] for c in ("man_x", "man_y", "man_z")], 1)
        quat = np.stack([info[c] for c in _QUAT], 1) if "qx" in info else np.tile(_IDENTITY, (len(idx), 1))
        quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)
        if "frame_idx" in info:
            frames, state = np.unique(info["frame_idx"], return_inverse=True)
        else:                                   # a frame per pose of the person, in order of appearance
            keys: dict = {}
            state = np.asarray([keys.setdefault(tuple(np.round(np.r_[m, q], 9)), len(keys))
                                for m, q in zip(man, quat)], np.int64)
            frames = np.arange(len(keys), dtype=np.int64)
        state = np.asarray(state, np.int64).reshape(-1)
        H = len(frames)
        first = np.array([np.flatnonzero(state == h)[0] for h in range(H)])
        moved = np.linalg.norm(man - man[first[state]], axis=1) > tol
        turned = np.minimum(np.abs(quat - quat[first[state]]).max(1), np.abs(quat + quat[first[state]]).max(1)) > 1e-6
        odd = np.flatnonzero(moved | turned)
        if odd.size:
            r, f = int(odd[0]), int(first[state[odd[0]]])
            raise DatasetError(f"{info_path}: frame_idx {int(frames[state[r]])} holds two poses of the person: line "
                               f"{int(line[f])} has man {man[f].tolist()}, q {np.round(quat[f], 6).tolist()}, line "
                               f"{int(line[r])} man {man[r].tolist()}, q {np.round(quat[r], 6).tolist()}")
        # the moving device of each row is one of the static folder's positions
        ap = np.asarray(self.antenna_pos, np.float64)
        A = len(ap)
        rx = np.stack([info[c] for c in ("rx_x", "rx_y", "rx_z")], 1)
        ant = np.empty(len(rx), np.int64)
        for c0 in range(0, len(rx), 2048):
            d = np.linalg.norm(rx[c0:c0 + 2048, None] - ap[None], axis=2)
            ant[c0:c0 + 2048] = d.argmin(1)
            far = np.flatnonzero(d.min(1) > tol)
            if far.size:
                r = c0 + int(far[0])
                raise DatasetError(f"{info_path}:{int(line[r])}: rx {rx[r].tolist()} is not one of the positions of "
                                   f"{self.positions_file} (the nearest is {float(d[far[0]].min()):.4g} m away; "
                                   f"position_tolerance_m = {tol:g})")
        for c0 in range(0, A, 2048):   # two static positions closer than tol: a row would be either
            d = np.linalg.norm(ap[c0:c0 + 2048, None] - ap[None], axis=2)
            d[np.arange(d.shape[0]), c0 + np.arange(d.shape[0])] = np.inf
            close = np.argwhere(d <= tol)
            if close.size:
                i, j = sorted((c0 + int(close[0, 0]), int(close[0, 1])))
                raise DatasetError(f"{self.positions_file}: rows {i + 1} and {j + 1} are the same position (within "
                                   f"position_tolerance_m = {tol:g} m); a dynamic row there would be either")
        grid = np.full((H, A), -1, np.int64)
        for r in range(len(idx)):
            h, a = state[r], ant[r]
            if grid[h, a] >= 0:
                raise DatasetError(f"{info_path}: lines {int(line[grid[h, a]])} and {int(line[r])} are both frame_idx "
                                   f"{int(frames[h])} at {self.positions_file.name} row {a + 1} {ap[a].tolist()}")
            grid[h, a] = r
        holes = np.argwhere(grid < 0)
        if holes.size:
            h, a = (int(v) for v in holes[0])
            raise DatasetError(f"{info_path}: frame_idx {int(frames[h])} has no spectrum at {self.positions_file.name} "
                               f"row {a + 1} {ap[a].tolist()} ({len(holes)} (frame, position) pairs missing in all); "
                               f"every frame needs one at each of the static folder's {A} positions")
        self._dynamic_files = [[files[int(idx[r])] for r in row] for row in grid]
        self.person_pos = np.concatenate([self.person_pos, man[first].astype(np.float32)])
        self.person_orientation = np.concatenate([self.person_orientation, quat[first]])
        self.frame_idx = np.asarray(frames, np.int64)
        return H, self._person_split(dynamic, idx, state, ant, H)

    def _person_split(self, dynamic: Path, idx: np.ndarray, state: np.ndarray, ant: np.ndarray,
                      H: int) -> tuple[np.ndarray, np.ndarray]:
        """(train, test) person indices (int64, sorted; index h is state h + 1): the frames of the
        dynamic train and test index files; without them the seeded split of :func:`make_split`."""
        tr, te, va = dynamic / "train_index.txt", dynamic / "test_index.txt", dynamic / "val_index.txt"
        if not (tr.is_file() and te.is_file()):
            sp = make_split(1, H, seed=0)
            return sp.person_train, sp.person_test
        known = {int(n): r for r, n in enumerate(idx)}
        rows = {f: _read_names(f, known) for f in (tr, te, va) if f.is_file()}
        names = list(rows)
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                both = np.intersect1d(rows[a], rows[b])
                if both.size:
                    raise DatasetError(f"{dynamic}: image {int(idx[both[0]]):05d} is in both {a.name} and {b.name}")
        h_tr, h_te = np.unique(state[rows[tr]]), np.unique(state[rows[te]])
        both = np.intersect1d(h_tr, h_te)
        if both.size:
            f = int(self.frame_idx[both[0]])
            raise DatasetError(f"{dynamic}: frame_idx {f} has spectra in both {tr.name} and {te.name}; a frame (a pose "
                               "of the person) is either a training or a test one")
        a_tr, a_te = self._antenna_split
        off = int(np.isin(ant[rows[tr]], a_te).sum() + np.isin(ant[rows[te]], a_tr).sum())
        if off:
            self._warn(f"{dynamic}: {off} images of {tr.name} / {te.name} lie at test / training positions of "
                       f"{self.static_path}'s index files; the static folder's split of the positions is kept "
                       "(training never sees a test position or a test frame)")
        return h_tr.astype(np.int64), h_te.astype(np.int64)

    def _warn(self, msg: str) -> None:
        warnings.warn(msg, stacklevel=3)
        self.warnings.append(msg)

    def __repr__(self) -> str:
        return (f"OneWalkDataset({str(self.path)!r}, task={self.task!r}, antennas={self.num_antennas}, "
                f"states={self.num_states})")

    def _files(self) -> list[tuple[str, Path]]:
        """(name, file) of every file read: the name relative to its folder, behind ``static/`` or
        ``dynamic/``."""
        out = []
        for tag, folder, names in (("static", self.static_path, [*POSITION_FILES, "gateway_info.yml", "train_index.txt",
                                                                 "test_index.txt", EXTRA]),
                                   ("dynamic", self.dynamic_path, [INFO, "train_index.txt", "val_index.txt",
                                                                   "test_index.txt", EXTRA])):
            if folder is not None:
                out += [(f"{tag}/{n}", folder / n) for n in names]
        out += [(f"static/spectrum/{f.name}", f) for f in self._static_files]
        for row in getattr(self, "_dynamic_files", []):
            out += [(f"dynamic/spectrums/{f.name}", f) for f in row]
        return out

    def fingerprint(self) -> str:
        """A hex digest that changes when the folders' content does (not where they lie): sha256
        over the position and info files, index files, gateway, ``rfmitsuba.json`` files and every
        image read, by name."""
        import hashlib

        h = hashlib.sha256()
        for name, f in self._files():
            if f.is_file():
                h.update(name.encode() + b"\0" + f.read_bytes() + b"\0")
        return h.hexdigest()

    def pas(self, state: int = 0) -> _StateImages:
        """The PAS of one state: float32 [A, 90, 360] in [0, 1] (the images / 255), indexed like an
        array (rows are converted as asked; ``np.asarray`` gives them all). Images are read on a
        state's first use."""
        s = int(state)
        if not 0 <= s < self.num_states:
            raise DatasetError(f"{self.path}: state {state} outside [0, {self.num_states})")
        if s not in self._images:
            files = self._static_files if s == 0 else self._dynamic_files[s - 1]
            codes = np.empty((len(files), *PAS_SHAPE), np.uint16)
            for a, f in enumerate(files):
                codes[a] = np.round(read_image(f).astype(np.float64) * 65535.0)
            self._images[s] = _StateImages(codes)
        return self._images[s]

    def channel(self, state: int = 0) -> np.ndarray:
        raise DatasetError(f"{self.path}: a One Walk folder stores no channels")

    def arrays(self, states: list[int] | None = None) -> dict[str, np.ndarray]:
        """Flat arrays (docs/conventions.md), row ``k = position in states * A + antenna``: pas
        float32 [K, 90, 360], antenna_pos float32 [K, 3], person_pos float32 [K, 3], state and
        antenna int64 [K]."""
        states = list(range(self.num_states)) if states is None else [int(s) for s in states]
        A = self.num_antennas
        return {"pas": np.concatenate([np.asarray(self.pas(s)) for s in states]) if states
                else np.zeros((0, *PAS_SHAPE), np.float32),
                "antenna_pos": np.tile(self.antenna_pos, (len(states), 1)),
                "person_pos": np.repeat(self.person_pos[states], A, axis=0),
                "state": np.repeat(np.asarray(states, np.int64), A),
                "antenna": np.tile(np.arange(A, dtype=np.int64), len(states))}


def read(path: str | Path, *, config: OneWalkConfig | None = None) -> OneWalkDataset:
    """Read a One Walk static folder, dynamic folder (with its static folder) or a folder holding
    both (:func:`layout`); DatasetError naming the file and the cause when something is missing,
    malformed or inconsistent."""
    return OneWalkDataset(path, config=config)


def _names_width(count: int) -> int:
    return max(5, len(str(count)))


def _save_images(folder: Path, pas, first: int, width: int) -> None:
    """Each PAS of ``pas`` (float [k, 90, 360]) as 8-bit greyscale ``folder/{first + i:0{width}d}.png``."""
    from PIL import Image

    for i, img in enumerate(to_uint8(np.asarray(pas, np.float32))):
        Image.fromarray(img).save(folder / f"{first + i:0{width}d}.png")


def _write_index(path: Path, numbers, width: int) -> None:
    path.write_text("".join(f"{int(n):0{width}d}\n" for n in sorted(numbers)))


def write(dataset, folder: str | Path) -> Path:
    """Write a dataset (:class:`rfmitsuba.data.store.Dataset`, or any with its interface) in the
    One Walk layout: ``folder/static`` (state 0) and, where it has person states, ``folder/dynamic``.

    Args:
        dataset: the source (``pas(state)``, ``antenna_pos``, ``person_pos``, ``fixed_pos``, ``split``,
            ``task``, ``frequency_hz``).
        folder: new or empty folder.
    Returns:
        The folder. Static images are numbered 1..A in antenna order; the image of state s > 0 at
        antenna a is number ``(s - 1) * A + a + 1``, with ``frame_idx = s - 1`` and the person's
        heading (``meta["person"]["headings_rad"]``; none: the identity) as its quaternion. The
        split's antenna indices become the static index files; the dynamic ones hold training
        antennas x training people (train), test x test (test) and the mixed pairs (val).
        ``rfmitsuba.json`` in each folder records the task, carrier, fixed device, array frame,
        read-out, source, split seed and the source's scene.
    """
    out = Path(folder)
    if out.exists() and any(out.iterdir()):
        raise DatasetError(f"{out} is not empty; refusing to write a One Walk dataset into it")
    A, S = int(dataset.num_antennas), int(dataset.num_states)
    sp = dataset.split
    meta = dict(getattr(dataset, "meta", {}) or {})
    r2w = getattr(dataset, "rx_to_world", None)
    q_array = list(_IDENTITY) if r2w is None else matrix_quaternion(r2w).tolist()
    fixed = [float(v) for v in np.asarray(dataset.fixed_pos, np.float64).reshape(3)]
    common = {"format": FORMAT, "task": dataset.task, "frequency_hz": float(dataset.frequency_hz), "fixed_pos": fixed,
              "array_orientation": q_array, "readout": str(getattr(dataset, "readout", "amplitude")),
              "source": str(dataset.path), "split_seed": int(sp.seed)}
    common.update({k: meta[k] for k in ("scene", "solver") if k in meta})
    static = out / "static"
    (static / "spectrum").mkdir(parents=True)
    w = _names_width(A)
    _save_images(static / "spectrum", dataset.pas(0), 1, w)
    write_positions(static / "rx_info.csv", dataset.antenna_pos)
    _write_gateway(static / "gateway_info.yml", fixed, list(_IDENTITY))
    _write_index(static / "train_index.txt", np.asarray(sp.antenna_train) + 1, w)
    _write_index(static / "test_index.txt", np.asarray(sp.antenna_test) + 1, w)
    (static / EXTRA).write_text(json.dumps({**common, "state": 0}, indent=1, allow_nan=False) + "\n")
    if S < 2:
        return out
    H = S - 1
    dyn = out / "dynamic"
    (dyn / "spectrums").mkdir(parents=True)
    w = _names_width(H * A)
    for s in range(1, S):
        _save_images(dyn / "spectrums", dataset.pas(s), (s - 1) * A + 1, w)
    quat = getattr(dataset, "person_orientation", None)
    heads = (meta.get("person") or {}).get("headings_rad") if isinstance(meta.get("person"), dict) else None
    if quat is not None and np.shape(quat) == (S, 4):
        quat = np.asarray(quat, np.float64)[1:]
    elif isinstance(heads, list) and len(heads) == H:
        quat = heading_quaternion(heads)
    else:
        quat = np.tile(_IDENTITY, (H, 1))
    hp = np.asarray(dataset.person_pos, np.float64)[1:]
    ap = np.asarray(dataset.antenna_pos, np.float64)
    lines = [",".join(INFO_COLUMNS)]
    groups = {"train": [], "val": [], "test": []}
    a_tr, a_te = set(int(i) for i in sp.antenna_train), set(int(i) for i in sp.antenna_test)
    h_tr, h_te = set(int(i) for i in sp.person_train), set(int(i) for i in sp.person_test)
    for h in range(H):
        for a in range(A):
            n = h * A + a + 1
            lines.append(",".join([str(n), *(f"{v:.9g}" for v in (*ap[a], *hp[h], *quat[h])), str(h)]))
            groups["train" if a in a_tr and h in h_tr else "test" if a in a_te and h in h_te else "val"].append(n)
    (dyn / INFO).write_text("\n".join(lines) + "\n")
    for name, nums in groups.items():
        _write_index(dyn / f"{name}_index.txt", nums, w)
    (dyn / EXTRA).write_text(json.dumps({**common, "static": "../static", "num_states": S}, indent=1,
                                        allow_nan=False) + "\n")
    return out
