"""A NeRF2-like simulated dataset (the "NeRF2-like" protocol, docs/conventions.md): Sionna RT ground
truth written as a NeRF2 RFID spectrum folder (:mod:`rfmitsuba.data.nerf2`).

The setup mirrors NeRF2's published RFID data:

- **moving TX** (a tag): ``num_tags`` positions inside a ``region_size`` box (1.6 x 1.3 x 0.9 m by
  default), sampled along a few smooth trajectories with consecutive tags ``step_m`` (9 mm) apart,
  as the real tags are (:func:`tag_trajectories`);
- **one fixed 4 x 4 gateway** at 920 MHz, horizontal (array frame = world frame, quaternion
  ``[0, 0, 0, 1]``), half-wavelength pitch (0.163 m; NeRF2's array has 0.16 m, ``pitch_m`` sets it),
  about 5 m from the tag region. In the built-in ``large_room`` (11 x 7.5 x 2.8 m) the layout is
  :data:`LAYOUTS`; other rooms get :func:`auto_layout` (as far apart as the room allows, up to 5 m);
- **channel** ``h`` [K, 16] from one Sionna RT solve (:class:`rfmitsuba.sim.simulate.Simulator`,
  departure directions at the gateway, :func:`rfmitsuba.rf.array.array_response`);
- **impairments**, in this order: optionally mutual coupling between the elements
  (:func:`coupling_matrix`, ``coupling_db``: each element picks up its neighbours' signals, so
  each element's response depends on the arrival direction, which no per-element calibration
  undoes), a fixed per-element phase offset (calibration error, uniform in
  ``+-phase_error_deg``, seeded), additive complex Gaussian noise at ``snr_db`` (a fixed noise floor:
  the SNR is that of the mean element power over all tags), then NeRF2's **phase-only Bartlett**
  read-out (``h_m / |h_m|``, :func:`rfmitsuba.rf.bartlett_ref.bartlett` with ``phase_only=True``) on
  the 90 x 360 PAS grid, min-max normalised and stored as 8-bit PNG; optionally the stated tag
  positions (``tx_pos.csv``) are off by Gaussian errors (``position_error_m``), as a tracker's are.
- **measured-style options**: an amplitude Bartlett read-out (``readout = "amplitude"``: the
  measured NeRF2 RFID images are amplitude images, docs/results/measured/diagnosis.md), and a
  **measurement drift** (:func:`measurement_drift`, after the phase offsets): every measurement
  multiplies each element's channel by its own gain ``exp(a + j b)``, with ``a`` and ``b`` Gaussian
  (``drift_db`` dB and ``drift_deg`` degrees standard deviation) and correlated from one tag of a
  trajectory to the next by ``drift_correlation``, as a reader's gains and the tag's coupling drift
  while it is carried along its path. It makes spectra of neighbouring tags differ more than any
  field of position at the carrier can, as the measured ones do.

The folder is written by :func:`rfmitsuba.data.nerf2.write` (spectrum/00001.png..., tx_pos.csv,
gateway_info.yml, the seeded 80/20 split of :func:`rfmitsuba.data.split.make_split` as
train_index.txt / test_index.txt) plus ``rfmitsuba.json`` recording the task ("tx"), carrier,
configuration, impairments (with the true per-element phase offsets), seeds, layout, materials and
timings. :func:`rfmitsuba.data.nerf2.read` reads it back.

Materials at 920 MHz: ITU-R P.2040 defines concrete, brick, plasterboard, metal and carpet tile only
from 1 GHz, and Sionna refuses other carriers. The scene is therefore loaded from a rewritten copy of
its XML in which every ITU material whose table does not cover the carrier becomes a fixed
``radio-material`` with the ITU formula of its nearest frequency range evaluated at the carrier
(an 8% extrapolation at 920 MHz); ``rfmitsuba.json`` lists them under ``materials``.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from ..core import backend, progress
from ..core import config as _config
from ..core.errors import ConfigError, DatasetError, SceneError
from ..core.allocation import check_fits
from ..core.folder_lock import folder_lock
from ..data import nerf2
from ..data.split import make_split
from ..data.store import _scene_record, first_difference, resolve_scene
from ..rf import array as antenna
from ..rf.bartlett_ref import bartlett
from ..rf.grid import PAS_SHAPE
from .generate import default_solver
from .geometry import RoomGeometry
from .simulate import Simulator, SolverConfig, versions

#: generator name recorded in rfmitsuba.json
GENERATOR = "rfmitsuba.sim.nerf2like"
#: NeRF2's RFID tag region, metres (x, y, z)
REGION_SIZE = (1.6, 1.3, 0.9)
#: distance between consecutive tags of one trajectory, metres (NeRF2's RFID tags: about 9 mm)
STEP_M = 0.009
#: target distance gateway -> tag-region centre, metres
DISTANCE_M = 5.0
#: height of the gateway above the floor, metres (the fixed-device height of docs/conventions.md)
GATEWAY_HEIGHT = 2.0
#: height of the tag region's bottom above the floor, metres
REGION_BOTTOM = 0.5
#: clearance of the tag region (every tag) to walls and furniture, metres
REGION_CLEARANCE = 0.1
#: clearance of the gateway to walls and furniture, metres
GATEWAY_CLEARANCE = 0.3
#: std of the random turn of a trajectory's direction per step, radians (smooth: ~0.35 rad per 50 steps)
TURN_RAD = 0.05
#: built-in layouts: tag-region centre and gateway position (world frame, metres). large_room: the
#: region (2.2..3.8, 0.95..2.25, 0.5..1.4) in the free south-west part, the gateway 5.01 m east of
#: its centre, 2 m above the floor, line of sight clear.
LAYOUTS = {"large_room": {"region_center": (3.0, 1.6, 0.95), "gateway_pos": (7.9, 1.6, 2.0)}}


# ---------------------------------------------------------------------------------- checks
def _number(value, name: str, *, lo: float | None = None, hi: float | None = None,
            allow_inf: bool = False) -> float:
    """``value`` as a float, ConfigError unless it is a real number (not bool) in [lo, hi]."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ConfigError(f"{name} must be a number, got {value!r}")
    v = float(value)
    if math.isnan(v) or (math.isinf(v) and not allow_inf):
        raise ConfigError(f"{name} must be finite, got {value!r}")
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise ConfigError(f"{name} must be in [{lo}, {hi}], got {value!r}")
    return v


def _integer(value, name: str, *, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ConfigError(f"{name} must be an integer, got {value!r}")
    if int(value) < lo:
        raise ConfigError(f"{name} must be >= {lo}, got {value!r}")
    return int(value)


def _point(value, name: str) -> np.ndarray:
    try:
        p = np.asarray(value, np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be [x, y, z] in metres, got {value!r}") from None
    if p.shape != (3,) or not np.isfinite(p).all():
        raise ConfigError(f"{name} must be 3 finite numbers [x, y, z] in metres, got {value!r}")
    return p


def _box_probe(lo: np.ndarray, hi: np.ndarray, *, spacing: float = 0.1) -> np.ndarray:
    """Grid points [N, 3] filling the box lo..hi (both faces included), about ``spacing`` apart."""
    axes = [np.linspace(a, b, max(2, math.ceil((b - a) / spacing) + 1)) for a, b in zip(lo, hi)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def check_layout(geom, region_lo: np.ndarray, region_hi: np.ndarray, gateway: np.ndarray) -> None:
    """ConfigError unless the tag region lies inside the room, clear of furniture by
    :data:`REGION_CLEARANCE`, and the gateway is free (:data:`GATEWAY_CLEARANCE`) and outside the
    region by at least 0.5 m. All arguments float [3], metres, world frame."""
    lo, hi = geom.bounds
    if np.any(region_lo < lo + REGION_CLEARANCE - 1e-9) or np.any(region_hi > hi - REGION_CLEARANCE + 1e-9):
        raise ConfigError(f"tag region {_fmt(region_lo)}..{_fmt(region_hi)} m is not inside the room interior "
                          f"{_fmt(lo)}..{_fmt(hi)} m with {REGION_CLEARANCE} m to the walls, floor and ceiling")
    probe = _box_probe(region_lo, region_hi)
    bad = np.flatnonzero(~geom.free_mask(probe, clearance=REGION_CLEARANCE))
    if bad.size:
        why = geom.explain(probe[bad[0]], clearance=REGION_CLEARANCE)
        raise ConfigError(f"tag region {_fmt(region_lo)}..{_fmt(region_hi)} m is not free: its point "
                          f"{_fmt(probe[bad[0]])} is {why}")
    if not geom.free_mask(gateway[None], clearance=GATEWAY_CLEARANCE)[0]:
        why = geom.explain(gateway, clearance=GATEWAY_CLEARANCE)
        raise ConfigError(f"gateway at {_fmt(gateway)} m is not free: {why}")
    gap = np.linalg.norm(np.maximum(0.0, np.maximum(region_lo - gateway, gateway - region_hi)))
    if gap < 0.5:
        raise ConfigError(f"gateway at {_fmt(gateway)} m is {gap:.2f} m from the tag region; keep it >= 0.5 m away")


def _fmt(p) -> str:
    return "(" + ", ".join(f"{float(v):.3f}" for v in np.asarray(p).reshape(-1)) + ")"


# ---------------------------------------------------------------------------------- layout
def auto_layout(geom, *, region_size=REGION_SIZE, distance_m: float = DISTANCE_M,
                spacing: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """A tag-region centre and a gateway position for a room without a built-in layout.

    Searches a ``spacing`` grid (metres) for a free region (its bottom :data:`REGION_BOTTOM` above
    the floor, or the lowest height above it, in 0.1 m steps, where the region fits beside the
    furniture) and a free gateway (:data:`GATEWAY_HEIGHT` above the floor) whose distance is closest to
    ``distance_m``, preferring pairs with a clear line of sight; ties go to the first in grid order.
    Returns (region centre float64 [3], gateway float64 [3]), metres; ConfigError when none fits.
    """
    size = np.asarray(region_size, np.float64)
    lo, hi = geom.bounds
    c_lo, c_hi = lo[:2] + REGION_CLEARANCE + size[:2] / 2, hi[:2] - REGION_CLEARANCE - size[:2] / 2
    top = hi[2] - REGION_CLEARANCE - size[2]            # highest possible bottom of the region
    if np.any(c_hi < c_lo) or top < lo[2] + REGION_CLEARANCE:
        raise ConfigError(f"a {size.tolist()} m tag region does not fit into the room {_fmt(lo)}..{_fmt(hi)} m")
    xs = np.arange(c_lo[0], c_hi[0] + 1e-9, spacing)
    ys = np.arange(c_lo[1], c_hi[1] + 1e-9, spacing)
    unit = _box_probe(-size / 2, size / 2, spacing=max(spacing, 0.15))
    centres = []
    # the lowest region bottom (from REGION_BOTTOM up, in 0.1 m steps) with any free place
    for bottom in np.arange(min(lo[2] + REGION_BOTTOM, top), top + 1e-9, 0.1):
        zc = bottom + size[2] / 2
        centres = [np.array([x, y, zc]) for x in xs for y in ys
                   if geom.free_mask(np.array([x, y, zc]) + unit, clearance=REGION_CLEARANCE).all()]
        if centres:
            break
    if not centres:
        raise ConfigError(f"no free place for a {size.tolist()} m tag region in the room (clearance "
                          f"{REGION_CLEARANCE} m to walls and furniture)")
    gz = lo[2] + GATEWAY_HEIGHT
    g = np.array([[x, y, gz] for x in np.arange(lo[0] + GATEWAY_CLEARANCE, hi[0] - GATEWAY_CLEARANCE + 1e-9, spacing)
                  for y in np.arange(lo[1] + GATEWAY_CLEARANCE, hi[1] - GATEWAY_CLEARANCE + 1e-9, spacing)])
    g = g[geom.free_mask(g, clearance=GATEWAY_CLEARANCE)] if len(g) else g
    if not len(g):
        raise ConfigError(f"no free place for the gateway {GATEWAY_HEIGHT} m above the floor")
    C = np.array(centres)
    d = np.linalg.norm(C[:, None] - g[None], axis=-1)                          # [C, G]
    gap = np.linalg.norm(np.maximum(0.0, np.maximum(C[:, None] - size / 2 - g[None], g[None] - C[:, None] - size / 2)),
                         axis=-1)
    cost = np.where(gap >= 0.5, np.abs(d - distance_m), np.inf)
    for i, j in zip(*np.unravel_index(np.argsort(cost, axis=None, kind="stable"), cost.shape)):
        if not np.isfinite(cost[i, j]):
            break
        if geom.segment_clear(g[j], C[i]):
            return C[i].copy(), g[j].copy()
    i, j = np.unravel_index(int(np.argmin(cost)), cost.shape)
    if not np.isfinite(cost[i, j]):
        raise ConfigError("no gateway position at least 0.5 m from a free tag region")
    return C[i].copy(), g[j].copy()


def tag_trajectories(n: int, *, lo, hi, num_trajectories: int, step_m: float = STEP_M,
                     rng: np.random.Generator, turn_rad: float = TURN_RAD) -> tuple[np.ndarray, np.ndarray]:
    """``n`` tag positions along ``num_trajectories`` smooth random paths inside the box lo..hi.

    Each path starts at a uniform point of the box with a uniform direction; every step moves
    ``step_m`` metres, after turning the direction by a Gaussian of ``turn_rad`` radians per axis,
    and reflects off the box's faces. Consecutive tags of one path are exactly ``step_m`` apart.

    Returns:
        (positions float64 [n, 3] metres, trajectory id int64 [n]); paths are consecutive blocks of
        nearly equal length (the first ones take the remainder).
    """
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    sizes = np.full(num_trajectories, n // num_trajectories)
    sizes[: n % num_trajectories] += 1
    out, ids = [], []
    for t, m in enumerate(sizes):
        p = lo + (hi - lo) * rng.random(3)
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        pts = [p]
        for _ in range(int(m) - 1):
            d = d + turn_rad * rng.normal(size=3)
            d /= np.linalg.norm(d)
            q = p + step_m * d
            flip = (q < lo) | (q > hi)
            if flip.any():
                d = np.where(flip, -d, d)
                q = p + step_m * d
            p = q
            pts.append(p)
        out.append(np.array(pts))
        ids.append(np.full(int(m), t, np.int64))
    return np.concatenate(out), np.concatenate(ids)


# ---------------------------------------------------------------------------------- mutual coupling
def coupling_matrix(level_db: float, *, rng: np.random.Generator, rows: int = antenna.ROWS,
                    cols: int = antenna.COLS) -> np.ndarray:
    """A reciprocal mutual-coupling matrix ``C`` of the ``rows x cols`` array (x fastest): the
    coupled channel is ``C h``. ``C = I + K``, ``K`` symmetric; an element couples to each of its
    row and column neighbours with magnitude ``10^(level_db / 20)`` and to its diagonal
    neighbours 6 dB below that, each pair with its own uniform random phase (elements farther
    apart: none).

    Args:
        level_db: coupling of adjacent elements [dB], finite (a patch array at half a wavelength:
            about -15 to -25 dB).
        rng: draws the phases.
    Returns:
        complex128 [rows*cols, rows*cols].
    """
    n = rows * cols
    r, c = np.divmod(np.arange(n), cols)
    d2 = (r[:, None] - r[None]) ** 2 + (c[:, None] - c[None]) ** 2
    mag = np.where(d2 == 1, 1.0, np.where(d2 == 2, 0.5, 0.0)) * 10 ** (level_db / 20)
    phase = rng.uniform(-np.pi, np.pi, (n, n))
    phase = np.triu(phase, 1) + np.triu(phase, 1).T                 # reciprocity: C = C^T
    return np.eye(n) + mag * np.exp(1j * phase)


# ---------------------------------------------------------------------------------- scene at the carrier
def measurement_drift(trajectory: np.ndarray, *, magnitude_db: float, phase_deg: float, correlation: float,
                      rng: np.random.Generator, elements: int = antenna.ROWS * antenna.COLS) -> np.ndarray:
    """Per-measurement element gains ``exp(a + j b)``: complex128 [K, elements].

    Args:
        trajectory: int [K] the trajectory of each tag, tags of one trajectory consecutive and in
            the order they were measured.
        magnitude_db: standard deviation of each gain's magnitude [dB] (``a = ln(10)/20 * N(0, s^2)``).
        phase_deg: standard deviation of each gain's phase [degrees].
        correlation: correlation of a gain between consecutive tags of one trajectory [1, in [0, 1)]:
            ``z_k = rho z_(k-1) + sqrt(1 - rho^2) e_k`` (a stationary AR(1) process per element, restarted
            at each trajectory's first tag).
        rng: the generator.
    """
    traj = np.asarray(trajectory)
    if not 0 <= correlation < 1:
        raise ConfigError(f"drift_correlation must be in [0, 1), got {correlation!r}")
    k = len(traj)
    e = rng.standard_normal((2, k, elements))
    z = np.empty_like(e)
    new = np.r_[True, traj[1:] != traj[:-1]]
    c = math.sqrt(1.0 - correlation ** 2)
    for i in range(k):
        z[:, i] = e[:, i] if new[i] else correlation * z[:, i - 1] + c * e[:, i]
    a = z[0] * (magnitude_db * math.log(10.0) / 20.0)
    b = z[1] * math.radians(phase_deg)
    return np.exp(a + 1j * b)


def scene_for_carrier(xml: Path, frequency_hz: float, folder: Path) -> tuple[Path, dict]:
    """The scene XML to load at ``frequency_hz``: ``xml`` itself when Sionna's ITU table covers every
    material at that carrier, else a rewritten copy in ``folder`` (meshes referenced by absolute path)
    where each uncovered ITU material is a fixed ``radio-material`` evaluated at the carrier from its
    nearest ITU frequency range.

    Returns (XML path, {material id: record}) with, per material, its ITU type, thickness (m),
    relative permittivity, conductivity (S/m) and whether it was extrapolated (``itu_range_ghz``).
    """

    backend.variant()
    from sionna.rt.radio_materials.itu import ITU_MATERIALS_PROPERTIES

    f_ghz = float(frequency_hz) / 1e9
    try:
        tree = ET.parse(xml)
    except ET.ParseError as e:
        raise SceneError(f"{xml}: not valid XML ({e})") from None
    record, changed = {}, False
    for bsdf in tree.getroot().iter("bsdf"):
        if bsdf.get("type") != "itu-radio-material":
            continue
        kids = {c.get("name"): c for c in bsdf}
        mid = bsdf.get("id", "?")
        itu = kids["type"].get("value") if "type" in kids else None
        if itu not in ITU_MATERIALS_PROPERTIES:
            raise SceneError(f"{xml}: material {mid!r} has unknown ITU type {itu!r}")
        table = ITU_MATERIALS_PROPERTIES[itu]
        inside = [r for r in table if r[0] <= f_ghz <= r[1]]
        # the covering range, else the nearest one (in log frequency)
        rng_ = inside[0] if inside else min(
            table, key=lambda r: abs(math.log(f_ghz / (r[0] if f_ghz < r[0] else r[1]))))
        a, b, c, d = table[rng_]
        thick = float(kids["thickness"].get("value")) if "thickness" in kids else None
        record[mid] = {"itu_type": itu, "thickness_m": thick, "relative_permittivity": a * f_ghz ** b,
                       "conductivity_s_per_m": c * f_ghz ** d, "itu_range_ghz": list(rng_),
                       "extrapolated": not inside}
        if inside:
            continue
        changed = True
        bsdf.set("type", "radio-material")
        bsdf.remove(kids["type"])
        ET.SubElement(bsdf, "float", name="relative_permittivity", value=repr(a * f_ghz ** b))
        ET.SubElement(bsdf, "float", name="conductivity", value=repr(c * f_ghz ** d))
    if not changed:
        return xml, record
    for s in tree.getroot().iter("string"):
        if s.get("name") == "filename" and not Path(s.get("value", "")).is_absolute():
            s.set("value", str((xml.parent / s.get("value")).resolve()))
    out = Path(folder) / f"{xml.stem}-{round(float(frequency_hz))}hz.xml"
    tree.write(out)
    return out, record


# ---------------------------------------------------------------------------------- the folder
def _stale_tmp(out: Path) -> None:
    """Remove temporary folders of ``out`` left by runs that died (their pid is gone)."""
    for t in out.parent.glob(f".{out.name}.tmp-*"):
        try:
            pid = int(t.name.rsplit("-", 1)[1])
        except ValueError:
            continue
        if pid != os.getpid():
            try:
                os.kill(pid, 0)
                continue
            except ProcessLookupError:
                pass
            except PermissionError:
                continue
        shutil.rmtree(t, ignore_errors=True)


def _existing(out: Path, config: dict) -> bool:
    """True when ``out`` is a complete folder of this configuration; False when it is absent or
    empty; DatasetError when it holds something else (the first differing key named)."""

    if not out.exists():
        return False
    if not out.is_dir():
        raise DatasetError(f"{out} exists and is not a folder")
    if not any(out.iterdir()):
        return False
    extra = out / nerf2.EXTRA
    try:
        rec = json.loads(extra.read_text())
    except (OSError, ValueError):
        rec = None
    if not isinstance(rec, dict) or rec.get("generator") != GENERATOR:
        raise DatasetError(f"{out} is not empty and not a NeRF2-like folder; refusing to write into it")
    diff = first_difference(rec.get("config"), config)
    if diff is not None:
        raise DatasetError(f"{out} holds a NeRF2-like dataset of another configuration (config.{diff[0]} is "
                           f"{diff[1]!r} there and {diff[2]!r} in this call); choose another folder or delete it")
    ds = nerf2.read(out)
    if ds.num_antennas != config["num_tags"]:
        raise DatasetError(f"{out}: {ds.num_antennas} spectra, expected {config['num_tags']}; delete the folder")
    return True


def make_nerf2like(out: str | Path, *, num_tags: int = 200, snr_db: float = 20.0, phase_error_deg: float = 30.0,
                   seed: int = 0, scene: str | Path = "large_room", frequency_hz: float = nerf2.NERF2_FREQUENCY_HZ,
                   region_center=None, region_size=REGION_SIZE, gateway_pos=None, num_trajectories: int = 4,
                   step_m: float = STEP_M, pitch_m: float | None = None, solver=None,
                   diffuse: float = 0.0, coupling_db: float = -math.inf, position_error_m: float = 0.0,
                   readout: str = "phase_only", drift_db: float = 0.0, drift_deg: float = 0.0,
                   drift_correlation: float = 0.0, quiet: bool = True) -> Path:
    """Simulate a NeRF2-like RFID dataset and write it as a NeRF2 spectrum folder (module docstring).

    Args:
        out: the folder to write [path]; new, empty, or a complete folder of the same configuration
            (then returned as it is, nothing is simulated). The folder is written as
            ``.<name>.tmp-<pid>`` beside it and renamed when complete, so ``out`` is either complete
            or absent; a temporary folder left by a run that died is removed by the next call.
        num_tags: tag (moving TX) positions, >= 10 [count].
        snr_db: signal-to-noise ratio of the mean element power over all tags [dB]; ``inf`` for no noise.
        phase_error_deg: per-element phase offsets are uniform in +-this [degrees], in [0, 180].
        seed: seeds the trajectories, phase offsets, noise and the 80/20 split [integer >= 0].
        scene: built-in room name or scene XML path; ``large_room`` fits the 5 m layout.
        frequency_hz: carrier [Hz] (NeRF2's RFID gateway: 920 MHz).
        region_center: centre of the tag region [m, world frame, (x, y, z)]; default: :data:`LAYOUTS`
            for the scene, else :func:`auto_layout`.
        region_size: extent of the tag region [m, (x, y, z)].
        gateway_pos: centre of the fixed 4x4 array [m, world frame]; default as ``region_center``.
        num_trajectories: smooth tag paths [count], each with >= 2 tags.
        step_m: distance between consecutive tags of a path [m].
        pitch_m: element pitch [m]; default half a wavelength (0.163 m at 920 MHz).
        solver: :class:`rfmitsuba.sim.simulate.SolverConfig`; default
            :func:`rfmitsuba.sim.generate.default_solver` for the room.
        diffuse: scattering coefficient of every material in [0, 1] [1]; above 0, Sionna RT also
            traces diffuse reflections (``SolverConfig.diffuse_reflection``), the part of a real
            room's response that no specular path draws: rough walls and furniture scatter a
            fraction of the energy towards every tag. 0 (the default): specular paths only.
        coupling_db: mutual coupling of adjacent elements [dB] (:func:`coupling_matrix`, seeded
            by ``seed``), applied to the channel before the phase offsets; -inf (the default): none.
        position_error_m: standard deviation per axis of the errors of the stated tag positions [m]:
            ``tx_pos.csv`` holds each tag's position plus Gaussian noise (seeded by ``seed``), while
            its spectrum comes from where the tag was, as a measured folder's tracked positions
            are off; the true positions go to ``rfmitsuba.json``. 0 (the default): exact.
        readout: "phase_only" (NeRF2's, the default) or "amplitude" (the Bartlett image of the channels
            as they are, element magnitudes included).
        drift_db, drift_deg: standard deviations of the measurement drift's element gains [dB] and
            phases [degrees] (:func:`measurement_drift`); 0 (the default): none.
        drift_correlation: correlation of the drift between consecutive tags of a trajectory [1, in [0, 1)].
        quiet: no progress output.
    Returns:
        The folder [Path]; :func:`rfmitsuba.data.nerf2.read` reads it.
    Raises:
        ConfigError: a bad option (NaN SNR, num_tags < 10, the tag region or gateway outside the room
            or in furniture, ...). DatasetError: ``out`` is not empty and holds something else.
        SceneError: unknown or broken scene.
    """

    t_start = time.perf_counter()
    num_tags = _integer(num_tags, "num_tags", lo=10)
    # the spectra (float32 [num_tags, 90, 360]) and a copy of them while they are written
    check_fits(2.0 * num_tags * PAS_SHAPE[0] * PAS_SHAPE[1] * 4, what=f"{num_tags} tags' spectra", option="--tags")
    snr = _number(snr_db, "snr_db", allow_inf=True)
    if snr == -math.inf:
        raise ConfigError(f"snr_db must be finite or +inf (no noise), got {snr_db!r}")
    phase_err = _number(phase_error_deg, "phase_error_deg", lo=0.0, hi=180.0)
    seed = _integer(seed, "seed", lo=0)
    f_hz = _number(frequency_hz, "frequency_hz", lo=1.0)
    lam = antenna.wavelength(f_hz)
    num_trajectories = _integer(num_trajectories, "num_trajectories", lo=1)
    if num_tags < 2 * num_trajectories:
        raise ConfigError(f"num_trajectories {num_trajectories} needs num_tags >= {2 * num_trajectories}, "
                          f"got {num_tags}")
    size = _point(region_size, "region_size")
    if np.any(size <= 0):
        raise ConfigError(f"region_size must be positive, got {size.tolist()}")
    step = _number(step_m, "step_m", lo=0.0)
    if not 0 < step < size.min() / 2:
        raise ConfigError(f"step_m must be in (0, {size.min() / 2:g}) m (half the region's smallest side), "
                          f"got {step_m!r}")
    pitch = lam / 2 if pitch_m is None else _number(pitch_m, "pitch_m", lo=0.0)
    if pitch <= 0:
        raise ConfigError(f"pitch_m must be positive, got {pitch_m!r}")
    if solver is not None and not isinstance(solver, (SolverConfig, dict)):
        raise ConfigError(f"solver must be a SolverConfig or a dict, got {type(solver).__name__}")
    out = Path(out)

    xml = resolve_scene(scene)
    geom = RoomGeometry.from_xml(xml)
    preset = LAYOUTS.get(xml.stem, {}) if Path(str(scene)).suffix.lower() != ".xml" else {}
    if region_center is None or gateway_pos is None:
        auto = (None, None) if preset else auto_layout(geom, region_size=size)
    centre = _point(region_center, "region_center") if region_center is not None else \
        np.asarray(preset.get("region_center", auto[0]), np.float64)
    gateway = _point(gateway_pos, "gateway_pos") if gateway_pos is not None else \
        np.asarray(preset.get("gateway_pos", auto[1]), np.float64)
    r_lo, r_hi = centre - size / 2, centre + size / 2
    check_layout(geom, r_lo, r_hi, gateway)
    solver = default_solver(geom) if solver is None else solver
    if isinstance(solver, dict):
        solver = _config.from_dict(SolverConfig, solver)
    diffuse = _number(diffuse, "diffuse", lo=0.0, hi=1.0)
    coupling = _number(coupling_db, "coupling_db", allow_inf=True)
    if coupling > 0:                                   # +inf included
        raise ConfigError(f"coupling_db must be finite and <= 0 dB, or -inf (none), got {coupling_db!r}")
    pos_err = _number(position_error_m, "position_error_m", lo=0.0, hi=0.5)
    if readout not in ("phase_only", "amplitude"):
        raise ConfigError(f"readout must be 'phase_only' or 'amplitude', got {readout!r}")
    drift_db = _number(drift_db, "drift_db", lo=0.0, hi=40.0)
    drift_deg = _number(drift_deg, "drift_deg", lo=0.0, hi=180.0)
    drift_rho = _number(drift_correlation, "drift_correlation", lo=0.0, hi=0.999)
    drift = drift_db > 0 or drift_deg > 0
    if diffuse > 0:
        solver = dataclasses.replace(solver, diffuse_reflection=True)
    solver.check()

    config = {"num_tags": num_tags, "snr_db": "inf" if math.isinf(snr) else snr, "phase_error_deg": phase_err,
              "seed": seed, "scene": str(scene), "frequency_hz": f_hz, "region_center": centre.tolist(),
              "region_size": size.tolist(), "gateway_pos": gateway.tolist(), "num_trajectories": num_trajectories,
              "step_m": step, "pitch_m": pitch, "solver": _config.to_dict(solver)}
    if diffuse > 0:   # only then: a folder made before the option existed keeps its configuration
        config["scattering_coefficient"] = diffuse
    if math.isfinite(coupling):
        config["coupling_db"] = coupling
    if pos_err > 0:
        config["position_error_m"] = pos_err
    if readout != "phase_only":    # as the other options: a folder made before them keeps its configuration
        config["readout"] = readout
    if drift:
        config["drift"] = {"db": drift_db, "deg": drift_deg, "correlation": drift_rho}
    out.parent.mkdir(parents=True, exist_ok=True)
    # one writer per folder: a second nerf2like into the same --out is refused, naming the first
    # (the lock sits in a sidecar folder, since --out itself appears only when complete)
    with folder_lock(out.parent / f".{out.name}.writer", what=f"nerf2like into {out}"):
        _stale_tmp(out)
        if _existing(out, config):
            return out

        # ---- tags, then one Sionna solve from the gateway to every tag
        tags, traj = tag_trajectories(num_tags, lo=r_lo, hi=r_hi, num_trajectories=num_trajectories, step_m=step,
                                      rng=np.random.default_rng([seed, 1]))
        tags = np.round(tags, 7)                      # what tx_pos.csv stores (%.9g), so truth and file agree
        geom.check_points(tags, what="tag", clearance=0.05)
        pos = antenna.element_positions(f_hz, spacing_wavelengths=pitch / lam)
        with progress.bar(3, desc=f"nerf2-like {xml.stem}", unit="step", quiet=quiet) as pb, \
                tempfile.TemporaryDirectory(prefix="rfm-nerf2like-") as tmpd:
            load_xml, materials = scene_for_carrier(xml, f_hz, Path(tmpd))
            sim = Simulator(load_xml, fixed_pos=gateway, frequency_hz=f_hz, solver=solver)
            if diffuse > 0:
                sim.set_scattering(diffuse)
            sim.set_positions(tags)
            paths = sim.solve()
            solver_s = sim.timing.solver_s
            del sim
            pb.update(1)
            none = np.flatnonzero(paths.num_paths == 0)
            if none.size:
                raise DatasetError(f"tag {int(none[0])} at {_fmt(tags[none[0]])} received no paths from the gateway")
            # departure directions at the gateway (reciprocity, docs/conventions.md): the array's channel
            h = antenna.array_response(paths.a, paths.u_fixed, frequency_hz=f_hz, positions=pos).astype(np.complex128)

            # ---- impairments: coupling, phase offsets, noise, phase-only Bartlett
            C = coupling_matrix(coupling, rng=np.random.default_rng([seed, 4])) if math.isfinite(coupling) else None
            if C is not None:
                h = h @ C.T
            offsets_deg = np.random.default_rng([seed, 2]).uniform(-phase_err, phase_err, h.shape[1])
            h_cal = h * np.exp(1j * np.deg2rad(offsets_deg))[None]
            if drift:
                h_cal = h_cal * measurement_drift(traj, magnitude_db=drift_db, phase_deg=drift_deg, correlation=drift_rho,
                                                  rng=np.random.default_rng([seed, 6]), elements=h.shape[1])
            signal_power = float(np.mean(np.abs(h) ** 2))
            if math.isinf(snr):
                noise_power = 0.0
                h_meas = h_cal
            else:
                noise_power = signal_power / 10 ** (snr / 10)
                g = np.random.default_rng([seed, 3]).normal(size=(*h.shape, 2))
                h_meas = h_cal + math.sqrt(noise_power / 2) * (g[..., 0] + 1j * g[..., 1])
            pas = bartlett(h_meas, frequency_hz=f_hz, positions=pos, phase_only=readout == "phase_only")
            stated = tags if pos_err == 0 else \
                np.round(tags + pos_err * np.random.default_rng([seed, 5]).normal(size=tags.shape), 7)
            pb.update(1)

            # ---- write into a temporary folder, then rename
            split = make_split(num_tags, 0, seed=seed)
            tmp = out.parent / f".{out.name}.tmp-{os.getpid()}"
            shutil.rmtree(tmp, ignore_errors=True)
            source = SimpleNamespace(pas=lambda state=0: pas, antenna_pos=stated, fixed_pos=gateway, split=split,
                                     person_pos=np.full((1, 3), np.nan), task="tx", frequency_hz=f_hz, num_states=1,
                                     path=f"sionna-rt:{xml.stem}")
            try:
                nerf2.write(source, tmp)
                d_tags = np.linalg.norm(tags - gateway, axis=1)
                steps = np.linalg.norm(np.diff(tags, axis=0), axis=1)[np.diff(traj) == 0]
                extra = json.loads((tmp / nerf2.EXTRA).read_text())
                extra.update({
                    "generator": GENERATOR,
                    "protocol": "NeRF2-like (docs/conventions.md): moving TX, blind room",
                    "config": config,
                    "scene": _scene_record(xml),
                    "materials": materials,
                    "layout": {"region_lo": r_lo.tolist(), "region_hi": r_hi.tolist(), "region_center": centre.tolist(),
                               "gateway_pos": gateway.tolist(), "gateway_orientation_xyzw": [0.0, 0.0, 0.0, 1.0],
                               "gateway_to_region_center_m": float(np.linalg.norm(centre - gateway)),
                               "gateway_to_tag_m": {"min": float(d_tags.min()), "max": float(d_tags.max())},
                               "line_of_sight_to_center": bool(geom.segment_clear(gateway, centre))},
                    "trajectories": {"count": num_trajectories, "step_m": step, "turn_rad_per_step": TURN_RAD,
                                     "id": traj.tolist(), "step_m_measured_mean": float(steps.mean())},
                    "array": {"rows": antenna.ROWS, "cols": antenna.COLS, "pitch_m": pitch,
                              "pitch_wavelengths": pitch / lam, "element_order": "x fastest: m = row * cols + col",
                              "orientation": "horizontal: array frame = world frame, normal +z",
                              "element_positions_m": pos.tolist()},
                    "impairments": {
                        "order": ["mutual coupling", "per-element phase offset", "measurement drift",
                                  "additive complex Gaussian noise", f"{readout} Bartlett", "stated tag positions"],
                        "drift": None if not drift else {
                            "magnitude_db": drift_db, "phase_deg": drift_deg, "correlation": drift_rho,
                            "applied_as": "h_km * exp(a_km + j b_km), AR(1) along each trajectory"},
                        "position_error": None if pos_err == 0 else {
                            "sigma_m_per_axis": pos_err, "applied_as": "tx_pos.csv = true position + N(0, sigma^2) per axis",
                            "rms_m": float(np.sqrt(np.mean(np.sum((stated - tags) ** 2, axis=1)))),
                            "true_tx_pos_m": tags.tolist()},
                        "coupling": None if C is None else {
                            "adjacent_db": coupling, "diagonal_db": coupling - 20 * math.log10(2),
                            "applied_as": "h <- C h (C symmetric)", "matrix_re": C.real.tolist(),
                            "matrix_im": C.imag.tolist()},
                        "diffuse_scattering": {"scattering_coefficient": diffuse,
                                               "traced": bool(solver.diffuse_reflection)},
                        "phase_offset": {"distribution": "uniform", "max_deg": phase_err,
                                         "per_element_deg": offsets_deg.tolist(), "applied_as": "h_m * exp(+j offset_m)"},
                        "noise": {"snr_db": config["snr_db"], "signal_power": signal_power, "noise_power": noise_power,
                                  "reference": "mean |h_m|^2 over all tags and elements (a fixed noise floor)"},
                        "readout": ("phase-only Bartlett: |sum_m conj(v_m) h_m/|h_m|| / 16, v_m = exp(+j 2pi/lambda r_m.d) "
                                    "(NeRF2's exp(-j ...) on its opposite-sign phases: the same image); per-image min-max, "
                                    "8-bit PNG") if readout == "phase_only" else
                                   ("amplitude Bartlett: |sum_m conj(v_m) h_m| / 16, v_m = exp(+j 2pi/lambda r_m.d); "
                                    "per-image min-max, 8-bit PNG"),
                    },
                    "seeds": {"trajectories": [seed, 1], "phase_offsets": [seed, 2], "noise": [seed, 3], "coupling": [seed, 4],
                              "position_error": [seed, 5], "drift": [seed, 6],
                              "split": seed,
                              "solver": solver.seed},
                    "solver": _config.to_dict(solver),
                    "timing": {"solver_s": solver_s, "total_s": time.perf_counter() - t_start},
                    "versions": versions(),
                })
                (tmp / nerf2.EXTRA).write_text(json.dumps(extra, indent=1, allow_nan=False) + "\n")
                _fsync_tree(tmp)
                if out.exists():
                    out.rmdir()                            # empty (checked by _existing)
                os.replace(tmp, out)
            except BaseException:
                shutil.rmtree(tmp, ignore_errors=True)
                raise
            pb.update(1)
        return out


def _fsync_tree(folder: Path) -> None:
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            with open(p, "rb") as f:
                os.fsync(f.fileno())
