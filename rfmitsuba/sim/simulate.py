"""Sionna RT wrapper: narrowband channels at the 4x4 array for both tasks (moving RX, moving TX).

One solve serves both tasks by reciprocity (environment facts, docs/conventions.md; checked against an
explicit reverse solve in tests/test_simulate.py). The solve always has one
isotropic transmitter at the fixed corner device and one isotropic receiver at
each antenna position (all batched into few ``PathSolver`` calls). From each
path's coefficient ``a``, delay ``tau`` and end directions:

- moving RX (array at the antenna positions): ``h_m = sum_p a_p e^{-j 2 pi f tau_p}
  e^{+j 2 pi/lambda r_m . u_r,p}`` with ``u_r`` the arrival direction at the receiver;
- moving TX (array fixed at the corner): the same with ``u_t``, the departure
  direction at the corner device.

This is Sionna's own synthetic-array rule (``synthetic_array=True``) applied
to whichever end carries the array (``array="synthetic"``, the default). With
``array="exact"`` (:meth:`Simulator.channels`) each of the 16 elements is traced as its own
isotropic antenna instead, so every element's channel comes from its own paths
(no plane-wave approximation): task rx places one receiver per element at each
antenna position (16 per position, one batched solve); task tx moves the fixed
device through its 16 element positions (16 solves). Paths are put in a canonical order
(delay, then coefficient) before summing in float64, so the channel does not
depend on the order in which the ray tracer's threads emit paths.

A person (or any perturber mesh) is added once with ``scene.edit(add=...)`` and
then moved by writing its vertex positions (absolute, not incremental), so a
state's geometry does not depend on the states simulated before it: a resumed
generation is bit-identical to an uninterrupted one.
"""
from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core import backend
from ..core.errors import ConfigError, PlacementError, SceneError
from ..rf import array as antenna

#: Name of the perturber object inside the Sionna scene.
PERSON_ID = "rfm-person"
#: Name of the fixed device inside the Sionna scene.
FIXED_ID = "rfm-fixed"
#: How the 16 element channels are obtained: Sionna's plane-wave rule about the array centre
#: (one trace per array position), or one trace per element.
ARRAYS = ("synthetic", "exact")


@dataclass
class SolverConfig:
    """Settings of Sionna RT's ``PathSolver`` call (recorded in meta.json)."""

    max_depth: int = 3
    samples_per_src: int = 100_000
    max_num_paths_per_src: int = 10_000_000
    los: bool = True
    specular_reflection: bool = True
    refraction: bool = True
    diffuse_reflection: bool = False
    diffraction: bool = False
    seed: int = 42
    #: receivers per PathSolver call
    batch_size: int = 1000
    #: Dr.Jit threads during the solve; 1 makes the result bit-reproducible across processes
    #: (with more threads path coefficients vary in the last float32 bit from run to run), 0 = all cores
    threads: int = 1

    def check(self) -> "SolverConfig":
        if self.max_depth < 0:
            raise ConfigError(f"solver.max_depth must be >= 0, got {self.max_depth}")
        for name in ("samples_per_src", "max_num_paths_per_src", "batch_size"):
            if getattr(self, name) < 1:
                raise ConfigError(f"solver.{name} must be >= 1, got {getattr(self, name)}")
        if self.threads < 0:
            raise ConfigError(f"solver.threads must be >= 0, got {self.threads}")
        if self.seed < 0:
            raise ConfigError(f"solver.seed must be >= 0, got {self.seed}")
        return self


@dataclass
class PathSet:
    """Paths between the fixed device and N antenna positions (padded to P paths, zeros where none).

    Attributes:
        a: complex128 [N, P], baseband coefficients ``a exp(-j 2 pi f tau)`` (unitless).
        u_fixed: float64 [N, P, 3], departure unit vectors at the fixed device.
        u_moving: float64 [N, P, 3], arrival unit vectors at the antenna positions.
        num_paths: int64 [N], valid paths per position.
    """

    a: np.ndarray
    u_fixed: np.ndarray
    u_moving: np.ndarray
    num_paths: np.ndarray

    def channels(self, task: str, *, frequency_hz: float) -> np.ndarray:
        """Channel at the 16 array elements: complex64 [N, 16] for task "rx" or "tx"."""
        if task == "rx":
            u = self.u_moving
        elif task == "tx":
            u = self.u_fixed
        else:
            raise ConfigError(f"task must be 'rx' or 'tx', got {task!r}")
        return antenna.array_response(self.a, u, frequency_hz=frequency_hz)

    def path_gain_db(self) -> np.ndarray:
        """Total (incoherent) path gain per position in dB: float64 [N]."""
        with np.errstate(divide="ignore"):
            return 10 * np.log10(np.sum(np.abs(self.a) ** 2, axis=1))


@dataclass
class Timing:
    """Seconds spent inside Sionna's PathSolver and in total (for the < 10% overhead target)."""

    solver_s: float = 0.0
    total_s: float = 0.0
    calls: int = 0
    extra: dict = field(default_factory=dict)


def _check_points(points: np.ndarray, what: str) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise PlacementError(f"{what} positions must be [N, 3], got shape {p.shape}")
    bad = np.flatnonzero(~np.isfinite(p).all(axis=1))
    if bad.size:
        raise PlacementError(f"{what} position {int(bad[0])} is not finite: {p[bad[0]].tolist()}")
    return p


class Simulator:
    """A loaded Sionna scene with the fixed device and a set of antenna positions.

    Args:
        scene_xml: Mitsuba/Sionna XML file (loaded with ``merge_shapes=False``).
        fixed_pos: float [3], metres, the fixed isotropic device (TX in task rx, array in task tx).
        frequency_hz: carrier, Hz.
        solver: :class:`SolverConfig`.
    """

    def __init__(self, scene_xml: str | Path, *, fixed_pos, frequency_hz: float = 2.4e9,
                 solver: SolverConfig | None = None):
        import rfmitsuba  # noqa: F401  (libLLVM first)


        backend.variant()  # selects the default variant on first use
        import mitsuba as mi
        from sionna.rt import PathSolver, PlanarArray, Transmitter, load_scene

        self.solver = (solver or SolverConfig()).check()
        self.frequency_hz = float(frequency_hz)
        antenna.wavelength(self.frequency_hz)
        self.fixed_pos = _check_points(np.reshape(fixed_pos, (1, 3)), "fixed device")[0]
        path = Path(scene_xml)
        if not path.is_file():
            raise SceneError(f"scene file {path} does not exist")
        _register_plugins()
        try:
            self.scene = load_scene(str(path), merge_shapes=False)
        except Exception as e:  # noqa: BLE001 - Mitsuba raises RuntimeError/ValueError with its own text
            raise SceneError(f"cannot load scene {path}: {e}") from None
        self.scene.frequency = self.frequency_hz
        iso = dict(num_rows=1, num_cols=1, pattern="iso", polarization="V")
        self.scene.tx_array = PlanarArray(**iso)
        self.scene.rx_array = PlanarArray(**iso)
        self.scene.add(Transmitter(FIXED_ID, position=mi.Point3f(*[float(x) for x in self.fixed_pos])))
        self._solver = PathSolver()
        self._receivers: list[str] = []
        self._person_faces: np.ndarray | None = None
        self._tmp = tempfile.TemporaryDirectory(prefix="rfm-person-")
        self.timing = Timing()

    def set_scattering(self, coefficient: float) -> None:
        """Set every scene material's scattering coefficient (in [0, 1]); needed for diffuse reflection.

        Sionna's XML loader rewrites ``itu-radio-material`` entries, so this is set after loading.
        """
        c = float(coefficient)
        if not 0.0 <= c <= 1.0:
            raise ConfigError(f"scattering coefficient must be in [0, 1], got {coefficient!r}")
        for mat in self.scene.radio_materials.values():
            if hasattr(mat, "scattering_coefficient"):
                mat.scattering_coefficient = c

    # ------------------------------------------------------------------ positions
    def set_positions(self, positions: np.ndarray) -> None:
        """Place one isotropic receiver at each antenna position (float [N, 3], metres)."""
        import mitsuba as mi
        from sionna.rt import Receiver

        p = _check_points(positions, "antenna")
        for name in self._receivers:
            self.scene.remove(name)
        self._receivers = []
        for i, x in enumerate(p):
            name = f"rfm-rx-{i}"
            self.scene.add(Receiver(name, position=mi.Point3f(float(x[0]), float(x[1]), float(x[2]))))
            self._receivers.append(name)
        self.positions = p

    # ------------------------------------------------------------------ the perturber
    def set_person(self, vertices: np.ndarray | None, faces: np.ndarray | None = None, *,
                  material=None) -> None:
        """Put the perturber mesh into the scene, move it, or remove it (``vertices=None``).

        Args:
            vertices: float [V, 3], metres, world frame; the absolute vertex positions of this state.
            faces: int [F, 3]; needed the first time (and fixes the topology for later calls).
            material: a Sionna radio material (or a name of one in the scene), first call only.
        """
        import drjit as dr
        import mitsuba as mi
        from sionna.rt import SceneObject

        if vertices is None:
            if self._person_faces is not None:
                self.scene.edit(remove=[PERSON_ID])
                self._person_faces = None
            return
        v = np.asarray(vertices, np.float64)
        if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
            raise PlacementError(f"person vertices must be finite [V, 3], got shape {v.shape}")
        if self._person_faces is None:
            if faces is None or material is None:
                raise ConfigError("the first set_person call needs faces and a material")
            f = np.asarray(faces, np.int64)
            ply = Path(self._tmp.name) / "person.ply"
            _write_ply(ply, v, f)
            obj = SceneObject(fname=str(ply), name=PERSON_ID, radio_material=material)
            self.scene.edit(add=[obj])
            self._person_faces = f
            self._person_nv = v.shape[0]
        if v.shape[0] != self._person_nv:
            raise PlacementError(f"person mesh has {v.shape[0]} vertices, the placed one {self._person_nv}")
        params = self.scene.mi_scene_params
        key = self.scene.get(PERSON_ID).mi_mesh.id() + ".vertex_positions"
        params[key] = dr.ravel(mi.Point3f(*[mi.Float(np.ascontiguousarray(v[:, i], np.float32))
                                            for i in range(3)]))
        params.update()
        self.scene.scene_geometry_updated()

    # ------------------------------------------------------------------ solving
    def solve(self) -> PathSet:
        """Trace paths from the fixed device to every antenna position (batched calls)."""
        t0 = time.perf_counter()
        if not self._receivers:
            raise ConfigError("no antenna positions: call set_positions first")
        parts = []
        names = list(self._receivers)
        bs = self.solver.batch_size
        batches = [names[s:s + bs] for s in range(0, len(names), bs)]
        try:
            for batch in batches:
                # Sionna solves for every receiver in the scene: the others are parked by removal,
                # from one batch straight to the next (7500 positions in 8 batches: 0.2 s of
                # scene edits, against 1.6 s when every position came back after each batch)
                if len(batches) > 1:
                    self._only(batch)
                parts.append(self._solve_batch(batch))
        finally:
            if len(batches) > 1:
                self._only(names)
        P = max(p.a.shape[1] for p in parts)
        out = PathSet(a=np.concatenate([_pad(p.a, P) for p in parts]),
                      u_fixed=np.concatenate([_pad(p.u_fixed, P) for p in parts]),
                      u_moving=np.concatenate([_pad(p.u_moving, P) for p in parts]),
                      num_paths=np.concatenate([p.num_paths for p in parts]))
        self.timing.total_s += time.perf_counter() - t0
        return out

    def _solve_batch(self, names: list[str]) -> PathSet:
        """Paths to ``names``, the receivers in the scene now (:meth:`solve` parks the others)."""
        import drjit as dr

        c = self.solver
        t = time.perf_counter()
        old_threads = dr.thread_count()
        if c.threads:
            dr.set_thread_count(c.threads)
        try:
            paths = self._solver(self.scene, max_depth=c.max_depth, max_num_paths_per_src=c.max_num_paths_per_src,
                                 samples_per_src=c.samples_per_src, synthetic_array=True, los=c.los,
                                 specular_reflection=c.specular_reflection, diffuse_reflection=c.diffuse_reflection,
                                 refraction=c.refraction, diffraction=c.diffraction, seed=c.seed)
            a_re, a_im = paths.a
            a = np.asarray(a_re, np.float64) + 1j * np.asarray(a_im, np.float64)
            tau = np.asarray(paths.tau, np.float64)
            valid = np.asarray(paths.valid, bool)
            ang = [np.asarray(x, np.float64) for x in (paths.theta_t, paths.phi_t, paths.theta_r, paths.phi_r)]
        finally:
            if c.threads:
                dr.set_thread_count(old_threads)
        self.timing.solver_s += time.perf_counter() - t
        self.timing.calls += 1
        n = len(names)
        a, tau, valid = a.reshape(n, -1), tau.reshape(n, -1), valid.reshape(n, -1)
        ang = [x.reshape(n, -1) for x in ang]
        a = np.where(valid, a * np.exp(-2j * np.pi * self.frequency_hz * tau), 0)
        # canonical order per position: valid first, then delay, then coefficient
        order = np.lexsort((a.imag, a.real, np.where(valid, tau, np.inf)), axis=1)
        take = lambda x: np.take_along_axis(x, order, axis=1)  # noqa: E731
        a = take(a)
        valid = take(valid)
        u_t = np.where(valid[..., None], antenna.unit_vectors(take(ang[0]), take(ang[1])), 0)
        u_r = np.where(valid[..., None], antenna.unit_vectors(take(ang[2]), take(ang[3])), 0)
        return PathSet(a=a, u_fixed=u_t, u_moving=u_r, num_paths=valid.sum(axis=1).astype(np.int64))

    def _only(self, keep: list[str]) -> None:
        import mitsuba as mi
        from sionna.rt import Receiver

        current = set(self.scene.receivers)
        for name in list(current):
            if name not in keep:
                self.scene.remove(name)
        idx = {n: i for i, n in enumerate(self._receivers)}
        for name in keep:
            if name not in current:
                x = self.positions[idx[name]]
                self.scene.add(Receiver(name, position=mi.Point3f(float(x[0]), float(x[1]), float(x[2]))))

    def channels(self, task: str, *, array: str = "synthetic") -> np.ndarray:
        """Solve and return the array channel for ``task``: complex64 [N, 16].

        Args:
            task: "rx" (the array at each antenna position) or "tx" (the array at the fixed device).
            array: "synthetic" (one trace per array position, element phases by the plane-wave
                rule) or "exact" (each element traced as its own isotropic antenna: 16 receivers
                per antenna position for task rx, 16 solves with the fixed device at each element
                for task tx). The element offsets are :func:`rfmitsuba.rf.array.element_positions`
                (the array frame is the world frame).
        """
        if task not in ("rx", "tx"):
            raise ConfigError(f"task must be 'rx' or 'tx', got {task!r}")
        if array not in ARRAYS:
            raise ConfigError(f"array must be one of {', '.join(ARRAYS)}, got {array!r}")
        if array == "synthetic":
            return self.solve().channels(task, frequency_hz=self.frequency_hz)
        if not self._receivers:
            raise ConfigError("no antenna positions: call set_positions first")
        r = antenna.element_positions(self.frequency_hz)
        centres = self.positions
        M = len(r)
        if task == "rx":
            self.set_positions((centres[:, None, :] + r[None, :, :]).reshape(-1, 3))
            try:
                h = self.solve().a.sum(axis=1).reshape(len(centres), M)
            finally:
                self.set_positions(centres)
        else:
            h = np.empty((len(centres), M), np.complex128)
            try:
                for m in range(M):
                    self._place_fixed(self.fixed_pos + r[m])
                    h[:, m] = self.solve().a.sum(axis=1)
            finally:
                self._place_fixed(self.fixed_pos)
        return h.astype(np.complex64)

    def _place_fixed(self, p: np.ndarray) -> None:
        import mitsuba as mi

        self.scene.get(FIXED_ID).position = mi.Point3f(*[float(x) for x in p])


def _pad(x: np.ndarray, P: int) -> np.ndarray:
    if x.shape[1] == P:
        return x
    pad = [(0, 0), (0, P - x.shape[1])] + [(0, 0)] * (x.ndim - 2)
    return np.pad(x, pad)


def _write_ply(path: Path, v: np.ndarray, f: np.ndarray) -> None:
    lines = ["ply", "format ascii 1.0", f"element vertex {len(v)}", "property float x", "property float y",
             "property float z", f"element face {len(f)}", "property list uchar int vertex_indices", "end_header"]
    lines += [f"{x:.7g} {y:.7g} {z:.7g}" for x, y, z in v]
    lines += [f"3 {a} {b} {c}" for a, b, c in f]
    path.write_text("\n".join(lines) + "\n")


def _register_plugins() -> None:
    try:
        from .. import plugins  # type: ignore[attr-defined]
    except ImportError:
        try:
            import rfmitsuba.plugins as plugins  # noqa: F811
        except ImportError:
            return
    reg = getattr(plugins, "register", None)
    if reg is not None:
        reg()


def versions() -> dict:
    """Versions of the packages that determine a simulation's result."""
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for pkg in ("rfmitsuba", "sionna-rt", "mitsuba", "drjit", "numpy"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = None
    return out
