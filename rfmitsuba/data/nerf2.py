"""NeRF2 spectrum dataset format (read and write), as used by NeRF2, WRF-GS(+) and GSRF.

A folder holds::

    spectrum/00001.png ...   90 x 360 8-bit greyscale, min-max normalised PAS (row = elevation
                             1..90 deg, column = azimuth 0..359 deg, PAS layout, docs/conventions.md)
    tx_pos.csv               header ``x,y,z``, one row per image (image n -> row n), metres
    gateway_info.yml         the fixed receiver array: position [x, y, z] and orientation
                             quaternion [x, y, z, w] (array frame -> world)
    train_index.txt          1-based image numbers, one per line (``00001``...)
    test_index.txt

NeRF2 is natively the moving-TX task (the gateway is the fixed array). A dataset
of the moving-RX task written here keeps the moving device's positions in
``tx_pos.csv`` and the fixed device as the gateway; the task, carrier and
origin are kept in an extra file ``rfmitsuba.json`` that NeRF2 readers ignore.
The YAML is written and read without a YAML library (the file is this one
fixed two-level layout).
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from ..core.errors import DatasetError
from ..rf.grid import PAS_SHAPE
from .split import Split, make_split

EXTRA = "rfmitsuba.json"


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
    from ..rf.bartlett_ref import normalize

    return np.round(normalize(pas) * 255.0).astype(np.uint8)


def _write_gateway(path: Path, position, orientation) -> None:
    p = ", ".join(f"{float(v):.9g}" for v in position)
    o = ", ".join(f"{float(v):.9g}" for v in orientation)
    path.write_text(f"gateway1:\n  position: [{p}]\n  orientation: [{o}]\n")


def _read_gateway(path: Path) -> tuple[np.ndarray, np.ndarray]:
    if not path.is_file():
        raise DatasetError(f"{path} is missing")
    data: dict[str, dict[str, list[float]]] = {}
    top = None
    for n, line in enumerate(path.read_text().splitlines(), 1):
        s = line.split("#", 1)[0].rstrip()
        if not s.strip():
            continue
        m_top = re.fullmatch(r"([A-Za-z0-9_]+):", s)
        m_key = re.fullmatch(r"\s+([A-Za-z0-9_]+):\s*\[([^\]]*)\]", s)
        if m_top:
            top = m_top.group(1)
            data[top] = {}
        elif m_key and top is not None:
            try:
                data[top][m_key.group(1)] = [float(v) for v in m_key.group(2).split(",")]
            except ValueError:
                raise DatasetError(f"{path}:{n}: not a list of numbers: {line.strip()!r}") from None
        else:
            raise DatasetError(f"{path}:{n}: cannot parse {line.strip()!r}")
    try:
        g = data["gateway1"]
        pos, quat = np.asarray(g["position"], np.float64), np.asarray(g["orientation"], np.float64)
    except KeyError as e:
        raise DatasetError(f"{path}: missing gateway1 key {e}") from None
    if pos.shape != (3,) or quat.shape != (4,) or not np.isfinite(pos).all() or not np.linalg.norm(quat) > 0:
        raise DatasetError(f"{path}: gateway1 needs position [x, y, z] and orientation [x, y, z, w]")
    return pos, quat


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
    (out / "spectrum").mkdir(parents=True)
    from PIL import Image

    imgs = to_uint8(np.asarray(dataset.pas(state)))
    for i, img in enumerate(imgs):
        Image.fromarray(img, mode="L").save(out / "spectrum" / f"{i + 1:05d}.png")
    pos = np.asarray(dataset.antenna_pos, np.float64)
    (out / "tx_pos.csv").write_text("x,y,z\n" + "".join(f"{x:.9g},{y:.9g},{z:.9g}\n" for x, y, z in pos))
    _write_gateway(out / "gateway_info.yml", dataset.fixed_pos, [0.0, 0.0, 0.0, 1.0])
    sp = dataset.split
    (out / "train_index.txt").write_text("".join(f"{i + 1:05d}\n" for i in sp.antenna_train))
    (out / "test_index.txt").write_text("".join(f"{i + 1:05d}\n" for i in sp.antenna_test))
    hp = np.asarray(dataset.human_pos[state], np.float64)
    extra = {"format": "rfmitsuba-nerf2/1", "task": dataset.task, "frequency_hz": dataset.frequency_hz,
             "source": str(dataset.path), "state": int(state),
             "human_pos": None if np.isnan(hp).any() else hp.tolist(), "split_seed": int(sp.seed)}
    (out / EXTRA).write_text(json.dumps(extra, indent=1) + "\n")
    return out


class NerfDataset:
    """A NeRF2 spectrum folder read with the :class:`rfmitsuba.data.store.Dataset` interface (one state).

    ``pas(0)`` is float32 [A, 90, 360] in [0, 1] (the 8-bit images / 255; already normalised).
    ``rx_to_world`` float64 [3, 3] is the gateway orientation (identity for our own files).
    """

    def __init__(self, folder: str | Path, *, frequency_hz: float | None = None):
        from PIL import Image

        self.path = Path(folder)
        spec = self.path / "spectrum"
        if not spec.is_dir():
            raise DatasetError(f"{self.path}: no spectrum/ folder, not a NeRF2 dataset")
        files = sorted(spec.glob("*.png"))
        if not files:
            raise DatasetError(f"{spec}: no PNG images")
        numbers = []
        for f in files:
            if not f.stem.isdigit():
                raise DatasetError(f"{f}: image names must be 1-based numbers like 00001.png")
            numbers.append(int(f.stem))
        A = len(files)
        if sorted(numbers) != list(range(1, A + 1)):
            raise DatasetError(f"{spec}: images must be numbered 1..{A} without gaps")
        extra = {}
        if (self.path / EXTRA).is_file():
            extra = json.loads((self.path / EXTRA).read_text())
        self.task = extra.get("task", "tx")
        self.frequency_hz = float(frequency_hz or extra.get("frequency_hz", 2.4e9))
        imgs = np.empty((A, *PAS_SHAPE), np.float32)
        for f in files:
            im = Image.open(f)
            arr = np.asarray(im.convert("L") if im.mode not in ("L", "I;16", "I") else im)
            if arr.shape != PAS_SHAPE:
                raise DatasetError(f"{f}: image is {arr.shape[0]}x{arr.shape[1]}, expected 90x360")
            scale = 65535.0 if arr.dtype == np.uint16 else 255.0
            imgs[int(f.stem) - 1] = arr / scale
        self._pas = imgs
        csv = self.path / "tx_pos.csv"
        try:
            pos = np.loadtxt(csv, delimiter=",", skiprows=1, ndmin=2)
        except (OSError, ValueError) as e:
            raise DatasetError(f"{csv}: missing or malformed ({e})") from None
        if pos.shape[1] != 3 or len(pos) < A or not np.isfinite(pos).all():
            raise DatasetError(f"{csv}: needs {A} finite rows x,y,z; got {pos.shape}")
        self.antenna_pos = pos[:A].astype(np.float32)
        self.fixed_pos, quat = _read_gateway(self.path / "gateway_info.yml")
        self.rx_to_world = quaternion_matrix(quat)
        self.num_antennas = A
        self.num_states = 1
        hp = extra.get("human_pos")
        self.human_pos = np.array([hp if hp is not None else [np.nan] * 3], np.float32)
        self.split = self._read_split(A)
        self.meta = {"format": "nerf2", "task": self.task, "frequency_hz": self.frequency_hz,
                     "num_antenna_positions": A, "num_states": 1, "fixed_pos": self.fixed_pos.tolist(),
                     "gateway_orientation_xyzw": quat.tolist(), "nerf2": extra}

    def _read_split(self, A: int) -> Split:
        tr, te = self.path / "train_index.txt", self.path / "test_index.txt"
        if not (tr.is_file() and te.is_file()):
            return make_split(A, 0, seed=0)
        idx = {}
        for name, f in (("train", tr), ("test", te)):
            try:
                vals = [int(t) for t in f.read_text().split()]
            except ValueError:
                raise DatasetError(f"{f}: entries must be 1-based image numbers") from None
            if vals and (min(vals) < 1 or max(vals) > A):
                raise DatasetError(f"{f}: image numbers outside 1..{A}")
            idx[name] = np.sort(np.asarray(vals, np.int64) - 1)
        if set(idx["train"]) & set(idx["test"]):
            raise DatasetError(f"{tr} and {te} share images")
        return Split(antenna_train=idx["train"], antenna_test=idx["test"], human_train=np.zeros(0, np.int64),
                     human_test=np.zeros(0, np.int64), seed=0)

    def __repr__(self) -> str:
        return f"NerfDataset({str(self.path)!r}, task={self.task!r}, antennas={self.num_antennas})"

    def pas(self, state: int = 0) -> np.ndarray:
        """float32 [A, 90, 360] in [0, 1]; only state 0 exists."""
        if int(state) != 0:
            raise DatasetError(f"{self.path}: a NeRF2 dataset has only state 0, asked for {state}")
        return self._pas

    def channel(self, state: int = 0) -> np.ndarray:
        raise DatasetError(f"{self.path}: a NeRF2 spectrum dataset stores no channels")

    def arrays(self, states: list[int] | None = None) -> dict[str, np.ndarray]:
        """Flat arrays (docs/conventions.md) (K = A): pas, antenna_pos, human_pos, state, antenna."""
        for s in states or [0]:
            self.pas(s)
        A = self.num_antennas
        return {"pas": self._pas, "antenna_pos": self.antenna_pos, "human_pos": np.repeat(self.human_pos, A, 0),
                "state": np.zeros(A, np.int64), "antenna": np.arange(A, dtype=np.int64)}


def read(folder: str | Path, *, frequency_hz: float | None = None) -> NerfDataset:
    """Read a NeRF2 spectrum folder; DatasetError naming the file when something is missing or malformed."""
    return NerfDataset(folder, frequency_hz=frequency_hz)
