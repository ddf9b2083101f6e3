"""NeRF2 spectrum dataset format (read and write), as used by NeRF2, WRF-GS(+) and GSRF.

A folder holds::

    spectrum/00001.png ...   90 x 360 8-bit greyscale, min-max normalised PAS (row = elevation
                             1..90 deg, column = azimuth 0..359 deg, PAS layout, docs/conventions.md)
    tx_pos.csv               one row per image (image n -> row n), metres; a header row
                             (``x,y,z``) is optional
    gateway_info.yml         the fixed receiver array: ``gateway1: {position: [x, y, z],
                             orientation: [x, y, z, w]}`` (quaternion, array frame -> world)
    train_index.txt          1-based image numbers, one per line (``00001``...)
    test_index.txt

Folders are read as published (NeRF2's RFID ``s23``, WRF-GS's ``data_test200``): the YAML
is read with PyYAML, so extra top-level keys (``dataset_name: s23``) and comments are
accepted; CRLF line ends, a UTF-8 byte-order mark, a header row and zero-padded index
numbers are accepted too. Anything else that is malformed raises :class:`DatasetError`
naming the file (and line, where there is one).

NeRF2 is natively the moving-TX task (the gateway is the fixed array). A folder without our
extra file is read with NeRF2's RFID defaults: moving TX, carrier :data:`NERF2_FREQUENCY_HZ`
(about 920 MHz; the 4 x 4 array's 0.16 m pitch is half a wavelength there). A dataset of the
moving-RX task written here keeps the moving device's positions in ``tx_pos.csv`` and the
fixed device as the gateway; the task, carrier and origin are kept in an extra file
``rfmitsuba.json`` that NeRF2 readers ignore (write one beside a measured folder to set
another carrier).
"""
from __future__ import annotations

import json
import math
import re
import warnings
from pathlib import Path

import numpy as np

from ..core.errors import DatasetError
from ..core.legacy_names import current_keys
from ..rf.bartlett_ref import normalize
from ..rf.grid import PAS_SHAPE
from .split import Split, make_split

EXTRA = "rfmitsuba.json"
#: carrier of NeRF2's RFID gateway, Hz (used when a folder does not say)
NERF2_FREQUENCY_HZ = 920e6


def quaternion_matrix(q) -> np.ndarray:
    """Rotation matrix float64 [3, 3] of a unit quaternion ``[x, y, z, w]`` (scalar last)."""
    x, y, z, w = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def to_uint8(pas: np.ndarray) -> np.ndarray:
    """Min-max normalise each image and quantise: uint8 [..., 90, 360]."""

    return np.round(normalize(pas) * 255.0).astype(np.uint8)


def _read_text(path: Path) -> str:
    """The text of ``path`` (UTF-8, an optional byte-order mark dropped); DatasetError when missing
    or not text."""
    if not path.is_file():
        raise DatasetError(f"{path} is missing")
    try:
        return path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise DatasetError(f"{path}: not a UTF-8 text file ({e.reason} at byte {e.start})") from None


def _write_gateway(path: Path, position, orientation) -> None:
    import yaml

    doc = {"gateway1": {"position": [float(v) for v in position], "orientation": [float(v) for v in orientation]}}
    path.write_text(yaml.safe_dump(doc, default_flow_style=None, sort_keys=False))


def _numbers(value, n: int) -> np.ndarray | None:
    """``value`` as float64 [n] when it is a list of n finite numbers (not booleans), else None."""
    if not isinstance(value, (list, tuple)) or len(value) != n:
        return None
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value):
        return None
    return np.asarray(value, np.float64)


def _read_gateway(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(position float64 [3] metres, quaternion float64 [4] ``[x, y, z, w]``) of ``gateway_info.yml``.

    The fixed array is the key ``gateway1`` (or the only key named ``gateway...``); other
    top-level keys (``dataset_name``) are ignored."""
    import yaml

    text = _read_text(path)
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f":{mark.line + 1}" if mark is not None else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise DatasetError(f"{path}{where}: not valid YAML ({problem})") from None
    if not isinstance(doc, dict):
        raise DatasetError(f"{path}: expected a mapping with a 'gateway1' key, got {type(doc).__name__}")
    names = [k for k in doc if isinstance(k, str) and re.fullmatch(r"gateway\d*", k)]
    key = "gateway1" if "gateway1" in doc else (names[0] if len(names) == 1 else None)
    if key is None:
        raise DatasetError(f"{path}: no 'gateway1' key (keys: {', '.join(map(str, doc))})")
    g = doc[key]
    if not isinstance(g, dict):
        raise DatasetError(f"{path}: {key} must hold 'position' and 'orientation', got {g!r}")
    pos = _numbers(g.get("position"), 3)
    quat = _numbers(g.get("orientation"), 4)
    if pos is None:
        raise DatasetError(f"{path}: {key}.position must be [x, y, z] (finite numbers, metres), got "
                           f"{g.get('position')!r}")
    if quat is None or not np.linalg.norm(quat) > 1e-9:
        raise DatasetError(f"{path}: {key}.orientation must be a non-zero quaternion [x, y, z, w], got "
                           f"{g.get('orientation')!r}")
    return pos, quat


def read_positions(path: Path) -> np.ndarray:
    """Rows of ``tx_pos.csv`` (or any x, y, z text file): float64 [N, 3] metres. A first row that is not numeric is a header;
    with a header naming x, y and z those columns are used, else the first three."""
    lines = [(n, ln.strip()) for n, ln in enumerate(_read_text(path).splitlines(), 1) if ln.strip()]
    if not lines:
        raise DatasetError(f"{path}: empty, expected one row x,y,z per image")

    def cells(s: str) -> list[str]:
        return [c.strip() for c in (s.split(",") if "," in s else s.split())]

    def is_number(c: str) -> bool:
        try:
            float(c)
            return True
        except ValueError:
            return False

    cols = [0, 1, 2]
    first = cells(lines[0][1])
    if not all(is_number(c) for c in first):
        head = [c.strip().strip('"').lower() for c in first]
        if all(k in head for k in ("x", "y", "z")):
            cols = [head.index(k) for k in ("x", "y", "z")]
        lines = lines[1:]
        if not lines:
            raise DatasetError(f"{path}: a header row and no positions")
    out = np.empty((len(lines), 3), np.float64)
    for r, (n, s) in enumerate(lines):
        row = cells(s)
        try:
            out[r] = [float(row[c]) for c in cols]
        except (IndexError, ValueError):
            raise DatasetError(f"{path}:{n}: expected numbers x,y,z, got {s[:80]!r}") from None
        if not np.isfinite(out[r]).all():
            raise DatasetError(f"{path}:{n}: position is not finite: {s[:80]!r}")
    return out


#: An image number as NeRF2's index files write it: ASCII digits, an optional '+'.
_NUMBER = re.compile(r"\+?[0-9]+", re.ASCII)


def _read_index(path: Path, count: int) -> np.ndarray:
    """0-based indices, sorted int64, of a 1-based index file (whitespace or comma separated)."""
    tokens = re.split(r"[\s,]+", _read_text(path).strip())
    tokens = [t for t in tokens if t]
    if not tokens:
        raise DatasetError(f"{path}: no image numbers")
    bad = next((t for t in tokens if not _NUMBER.fullmatch(t)), None)
    if bad is not None:   # ASCII digits only: str.isdigit() and int() take '²' or '٣' too
        raise DatasetError(f"{path}: entries must be 1-based image numbers, found {bad[:40]!r}")
    vals = np.asarray([int(t) for t in tokens], np.int64)
    if vals.min() < 1 or vals.max() > count:
        raise DatasetError(f"{path}: image numbers outside 1..{count} (found {int(vals.min())}..{int(vals.max())})")
    uniq, counts = np.unique(vals, return_counts=True)
    if (counts > 1).any():
        raise DatasetError(f"{path}: image number {int(uniq[counts > 1][0])} appears "
                           f"{int(counts[counts > 1][0])} times")
    return np.sort(vals - 1)


def read_image(path: Path) -> np.ndarray:
    """One spectrum image as float32 [90, 360] in [0, 1]: an 8-bit greyscale PNG / 255 (16-bit / 65535;
    colour images are converted to greyscale); DatasetError naming the file when it is not a
    readable 90 x 360 image."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            arr = np.asarray(im.convert("L") if im.mode not in ("L", "I;16", "I") else im)
    except (OSError, ValueError, SyntaxError) as e:
        raise DatasetError(f"{path}: not a readable image ({e})") from None
    if arr.shape != PAS_SHAPE:
        raise DatasetError(f"{path}: image is {'x'.join(map(str, arr.shape))}, expected 90x360")
    scale = 65535.0 if arr.dtype == np.uint16 else 255.0
    return (arr / scale).astype(np.float32)


def write_spectra(folder: Path, pas: np.ndarray) -> None:
    """``folder/spectrum/00001.png`` ...: each PAS of ``pas`` (float [K, 90, 360]) as an 8-bit
    greyscale image (:func:`to_uint8`), numbered from 1 in order."""
    from PIL import Image

    (folder / "spectrum").mkdir(parents=True, exist_ok=True)
    for i, img in enumerate(to_uint8(np.asarray(pas))):
        Image.fromarray(img, mode="L").save(folder / "spectrum" / f"{i + 1:05d}.png")


def write_positions(path: Path, pos: np.ndarray) -> None:
    """``pos`` (float [K, 3] m) as a ``tx_pos.csv``: a header ``x,y,z`` and one row per image."""
    pos = np.asarray(pos, np.float64).reshape(-1, 3)
    path.write_text("x,y,z\n" + "".join(f"{x:.9g},{y:.9g},{z:.9g}\n" for x, y, z in pos))


def write(dataset, folder: str | Path, *, state: int = 0) -> Path:
    """Write one state of a dataset (:class:`rfmitsuba.data.store.Dataset` or a NeRF2 one) in NeRF2 format.

    Args:
        dataset: the source (``pas(state)``, ``antenna_pos``, ``fixed_pos``, ``split``).
        folder: new or empty folder.
        state: which state (0 = empty room).
    Returns:
        The folder. Images are numbered 1..A in antenna order; the split's antenna
        train/test indices become the index files.
    """
    out = Path(folder)
    if out.exists() and any(out.iterdir()):
        raise DatasetError(f"{out} is not empty; refusing to write a NeRF2 dataset into it")
    if not 0 <= int(state) < dataset.num_states:
        raise DatasetError(f"state {state} outside [0, {dataset.num_states})")
    write_spectra(out, dataset.pas(state))
    write_positions(out / "tx_pos.csv", dataset.antenna_pos)
    _write_gateway(out / "gateway_info.yml", dataset.fixed_pos, [0.0, 0.0, 0.0, 1.0])
    sp = dataset.split
    (out / "train_index.txt").write_text("".join(f"{i + 1:05d}\n" for i in sp.antenna_train))
    (out / "test_index.txt").write_text("".join(f"{i + 1:05d}\n" for i in sp.antenna_test))
    hp = np.asarray(dataset.person_pos[state], np.float64)
    extra = {"format": "rfmitsuba-nerf2/1", "task": dataset.task, "frequency_hz": dataset.frequency_hz,
             "source": str(dataset.path), "state": int(state),
             "person_pos": None if np.isnan(hp).any() else hp.tolist(), "split_seed": int(sp.seed)}
    (out / EXTRA).write_text(json.dumps(extra, indent=1) + "\n")
    return out


class NerfDataset:
    """A NeRF2 spectrum folder read with the :class:`rfmitsuba.data.store.Dataset` interface (one state).

    ``pas(0)`` is float32 [A, 90, 360] in [0, 1] (the 8-bit images / 255; already normalised).
    ``rx_to_world`` float64 [3, 3] is the gateway orientation (identity for our own files).
    """

    def __init__(self, folder: str | Path, *, frequency_hz: float | None = None):
        self.path = Path(folder)
        spec = self.path / "spectrum"
        if not spec.is_dir():
            raise DatasetError(f"{self.path}: no spectrum/ folder, not a NeRF2 dataset")
        files = sorted(spec.glob("*.png"))
        if not files:
            raise DatasetError(f"{spec}: no PNG images")
        numbers = []
        for f in files:
            if not (f.stem.isascii() and f.stem.isdigit()):   # not "².png"
                raise DatasetError(f"{f}: image names must be 1-based numbers like 00001.png")
            numbers.append(int(f.stem))
        A = len(files)
        if sorted(numbers) != list(range(1, A + 1)):
            have = set(numbers)
            repeated = sorted({n for n in numbers if numbers.count(n) > 1})
            if repeated:   # 00001.png and 1.png
                raise DatasetError(f"{spec}: image number {repeated[0]} appears twice (e.g. 00001.png and 1.png)")
            missing = [n for n in range(1, max(numbers) + 1) if n not in have]
            raise DatasetError(f"{spec}: image {missing[0]:05d}.png is missing"
                               + (f" ({len(missing)} numbers missing in all)" if len(missing) > 1 else "")
                               + f"; images must be numbered 1..{max(numbers)} without gaps")
        extra = {}
        if (self.path / EXTRA).is_file():
            try:
                extra = current_keys(json.loads(_read_text(self.path / EXTRA)))
            except json.JSONDecodeError as e:
                raise DatasetError(f"{self.path / EXTRA}:{e.lineno}: not valid JSON ({e.msg})") from None
            if not isinstance(extra, dict):
                raise DatasetError(f"{self.path / EXTRA}: expected a JSON object")
        #: a folder as published (no rfmitsuba.json): measured spectra of NeRF2's tool
        self.measured = not extra
        imp = extra.get("impairments") if isinstance(extra.get("impairments"), dict) else {}
        ro = str(extra.get("readout", imp.get("readout", ""))).lower().replace("-", "_")
        #: "phase_only" (NeRF2's read-out; published folders and our NeRF2-like simulations) or "amplitude"
        self.readout = "phase_only" if (self.measured or ro.startswith("phase_only")) else "amplitude"
        self.task = extra.get("task", "tx")
        if self.task not in ("rx", "tx"):
            raise DatasetError(f"{self.path / EXTRA}: task must be 'rx' or 'tx', got {self.task!r}")
        f_hz = frequency_hz or extra.get("frequency_hz", NERF2_FREQUENCY_HZ)
        if not isinstance(f_hz, (int, float)) or not math.isfinite(f_hz) or f_hz <= 0:
            raise DatasetError(f"{self.path}: frequency_hz must be a positive number, got {f_hz!r}")
        self.frequency_hz = float(f_hz)
        csv = self.path / "tx_pos.csv"
        pos = read_positions(csv)
        self.warnings = []
        if len(pos) < A:
            raise DatasetError(f"{csv}: {len(pos)} positions for {A} images in spectrum/ (one row per image)")
        if len(pos) > A:
            named = [_read_index(f, len(pos)) for f in (self.path / "train_index.txt", self.path / "test_index.txt")
                     if f.is_file()]
            last = max((int(ix.max()) + 1 for ix in named if ix.size), default=0)
            if last > A:   # the index files name images past the last one: those are missing, not extra rows
                raise DatasetError(f"{spec}: image {A + 1:05d}.png is missing"
                                   + (f" (and the {last - A - 1} after it)" if last > A + 1 else "")
                                   + f": tx_pos.csv has {len(pos)} rows and the index files name images up to "
                                     f"{last}; images must be numbered 1..{last} without gaps")
            msg = (f"{csv}: {len(pos)} positions but only {A} images in spectrum/; images 1..{A} take the first "
                   f"{A} rows (is spectrum/ complete?)")
            warnings.warn(msg, stacklevel=2)
            self.warnings.append(msg)
        self.antenna_pos = pos[:A].astype(np.float32)
        self.fixed_pos, quat = _read_gateway(self.path / "gateway_info.yml")
        self.rx_to_world = quaternion_matrix(quat)
        imgs = np.empty((A, *PAS_SHAPE), np.float32)
        for f in files:
            imgs[int(f.stem) - 1] = read_image(f)
        self._pas = imgs
        self.num_antennas = A
        self.num_states = 1
        hp = extra.get("person_pos")
        if hp is not None and _numbers(hp, 3) is None:
            raise DatasetError(f"{self.path / EXTRA}: person_pos must be null or [x, y, z], got {hp!r}")
        self.person_pos = np.array([hp if hp is not None else [np.nan] * 3], np.float32)
        self.split = self._read_split(A)
        self.meta = {"format": "nerf2", "task": self.task, "frequency_hz": self.frequency_hz,
                     "num_antenna_positions": A, "num_states": 1, "fixed_pos": self.fixed_pos.tolist(),
                     "gateway_orientation_xyzw": quat.tolist(), "nerf2": extra, "warnings": self.warnings,
                     "readout": self.readout, "measured": self.measured}

    def _read_split(self, A: int) -> Split:
        """The published index files; without them, the seeded 80/20 split of :func:`make_split`."""
        tr, te = self.path / "train_index.txt", self.path / "test_index.txt"
        if not (tr.is_file() and te.is_file()):
            return make_split(A, 0, seed=0)
        train, test = _read_index(tr, A), _read_index(te, A)
        shared = np.intersect1d(train, test)
        if shared.size:
            raise DatasetError(f"{tr} and {te} share images (e.g. {int(shared[0]) + 1})")
        return Split(antenna_train=train, antenna_test=test, person_train=np.zeros(0, np.int64),
                     person_test=np.zeros(0, np.int64), seed=0)

    def __repr__(self) -> str:
        return f"NerfDataset({str(self.path)!r}, task={self.task!r}, antennas={self.num_antennas})"

    def fingerprint(self) -> str:
        """A hex digest that changes when the folder's content does: sha256 over its images,
        positions, gateway, index files and extra file, in name order."""
        import hashlib

        h = hashlib.sha256()
        names = ["tx_pos.csv", "gateway_info.yml", "train_index.txt", "test_index.txt", EXTRA]
        files = [self.path / n for n in names] + sorted((self.path / "spectrum").glob("*.png"))
        for f in files:
            if f.is_file():
                h.update(str(f.relative_to(self.path)).encode() + b"\0" + f.read_bytes() + b"\0")
        return h.hexdigest()

    def pas(self, state: int = 0) -> np.ndarray:
        """float32 [A, 90, 360] in [0, 1]; only state 0 exists."""
        if int(state) != 0:
            raise DatasetError(f"{self.path}: a NeRF2 dataset has only state 0, asked for {state}")
        return self._pas

    def channel(self, state: int = 0) -> np.ndarray:
        raise DatasetError(f"{self.path}: a NeRF2 spectrum dataset stores no channels")

    def arrays(self, states: list[int] | None = None) -> dict[str, np.ndarray]:
        """Flat arrays (docs/conventions.md) (K = A): pas, antenna_pos, person_pos, state, antenna."""
        for s in states or [0]:
            self.pas(s)
        A = self.num_antennas
        return {"pas": self._pas, "antenna_pos": self.antenna_pos, "person_pos": np.repeat(self.person_pos, A, 0),
                "state": np.zeros(A, np.int64), "antenna": np.arange(A, dtype=np.int64)}


def read(folder: str | Path, *, frequency_hz: float | None = None) -> NerfDataset:
    """Read a NeRF2 spectrum folder; DatasetError naming the file when something is missing or malformed."""
    return NerfDataset(folder, frequency_hz=frequency_hz)
