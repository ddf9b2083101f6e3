"""Dataset generation: place antennas in a room, walk the person, ray-trace every state with
Sionna RT (:mod:`rfmitsuba.sim.simulate`) and write the dataset store (:mod:`rfmitsuba.data.store`).

:func:`generate` writes one chunk per state (the empty room, then one per walk position),
resumes an interrupted run chunk by chunk (``repair`` re-simulates damaged chunks), and
records the configuration, seeds and versions in ``meta.json`` and the timings in
``timing.json``. :class:`GenerateConfig` is everything it simulates; :func:`quick_config`
is the ``--quick`` size.
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core import config as _config
from ..core import progress
from ..core.cluster import ClusterConfig, Task, session
from ..core.errors import ConfigError, DatasetError, PlacementError
from ..data.split import make_split
from ..data.store import (
    Dataset,
    _scene_record,
    _write_meta_json,
    base_meta,
    check_chunk,
    chunk_name,
    prepare_folder,
    remove_stale_tmp,
    resolve_scene,
    write_chunk,
)
from ..rf import bartlett_ref as _pas
from ..rf.grid import PAS_SHAPE
from . import person as person
from .geometry import RoomGeometry
from .simulate import ARRAYS, Simulator, SolverConfig, versions


@dataclass
class GenerateConfig:
    """What :func:`generate` simulates (every field is recorded in meta.json).

    Heights (``z_range``, ``corner_height``) are metres above the floor.
    """

    scene: str = "bedroom"
    task: str = "rx"
    positions: int = 900
    person_positions: int = 35
    material: str = "tissue"
    seed: int = 0
    frequency_hz: float = 2.4e9
    z_range: tuple[float, float] = (0.5, 2.0)
    #: distance of antenna positions to walls and furniture, metres
    clearance: float = 0.15
    #: extra horizontal distance of antenna positions (below head height) to every walk position, metres
    person_margin: float = 0.15
    corner_inset: float = 0.3
    corner_height: float = 2.0
    walk_duration_s: float = 60.0
    #: people walking through the room at once: person 1 walks the ``person_positions`` walk, each
    #: other one a walk of its own, never within :data:`PEOPLE_GAP_M` of another at the same frame
    people: int = 1
    #: material scattering coefficient set after loading when diffuse reflection is on
    scattering_coefficient: float = 0.3
    #: "synthetic" (one trace per array position, plane-wave element phases) or "exact" (each of
    #: the 16 elements traced as its own antenna; for at most EXACT_MAX_POSITIONS positions)
    array: str = "synthetic"
    solver: "Any" = None  # simulate.SolverConfig; None -> defaults for the room size


#: closest two people's bodies come at one frame, beyond their footprints' radii [m]
PEOPLE_GAP_M = 0.1
#: walks drawn for each further person before :func:`other_walks` gives up (each steers clear of the others)
WALK_ATTEMPTS = 50


def other_walks(geom: RoomGeometry, first: np.ndarray, *, people: int, n: int, duration_s: float,
                seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Walks of people 2..P, each clear of every earlier one at every frame.

    Args:
        geom: the room; first: float [n, 3] person 1's feet positions [m]; people: P; n: frames;
        duration_s: the walk's duration [s]; seed: the dataset's seed (person j's k-th draw uses
        ``[seed, j, k]``).

    Returns:
        (float64 [n, P - 1, 3] feet positions [m], float64 [n, P - 1] headings [rad]).

    Raises:
        PlacementError: no clear walk for a person in :data:`WALK_ATTEMPTS` draws.
    """
    from ..core.errors import PlacementError

    gap = 2.0 * person.radius() + PEOPLE_GAP_M
    walks, heads = [np.asarray(first, np.float64)], []
    for j in range(1, people):
        try:
            w = person.walk(geom, n=n, duration_s=duration_s, seed=int(np.random.SeedSequence([seed, j])
                                                                        .generate_state(1)[0]),
                            max_attempts=WALK_ATTEMPTS, avoid=np.stack(walks), gap_m=gap)
        except PlacementError:
            raise PlacementError(f"no walk for person {j + 1} in {WALK_ATTEMPTS} draws keeps {gap:.2f} m from the "
                                 f"others at every moment in {geom.path}; ask for fewer people") from None
        walks.append(np.asarray(w.positions))
        heads.append(np.asarray(w.headings))
    if people < 2:
        return np.zeros((n, 0, 3)), np.zeros((n, 0))
    return np.stack(walks[1:], axis=1), np.stack(heads, axis=1)


#: most antenna positions ``array="exact"`` accepts: it traces 16 antennas per position
EXACT_MAX_POSITIONS = 200

QUICK = {"positions": 36, "person_positions": 4, "samples_per_src": 20_000}


def quick_config(scene: str = "bedroom", **overrides) -> GenerateConfig:
    """The ``--quick`` configuration: 36 positions x (1 + 4) states at 2e4 samples per source."""

    # the walk keeps the full walk's step (60 s / 35 positions), so its straight steps stay short
    kw = {"scene": scene, "positions": QUICK["positions"], "person_positions": QUICK["person_positions"],
          "walk_duration_s": 60.0 * QUICK["person_positions"] / 35,
          "solver": SolverConfig(samples_per_src=QUICK["samples_per_src"])}
    kw.update(overrides)
    return GenerateConfig(**kw)


def place_antennas(geometry, n: int, *, rng: np.random.Generator, z_range: tuple[float, float],
                   clearance: float, walk_positions: np.ndarray, body_radius: float, body_height: float,
                   avoid: np.ndarray | None = None) -> np.ndarray:
    """``n`` antenna positions in the free volume, float64 [n, 3], metres.

    Never inside furniture (``clearance`` from walls and furniture), never inside the
    person at any walk position (horizontal distance > ``body_radius`` unless above
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
    """SolverConfig for a room: 1e5 samples per source, 3e5 for rooms over 50 m^2 floor (environment facts, docs/conventions.md)."""

    area = float(np.prod(geometry.size[:2]))
    samples = 300_000 if area > 50 else 100_000
    if quick:
        samples = QUICK["samples_per_src"]
    return SolverConfig(samples_per_src=samples)


def generate(out: str | Path, cfg: GenerateConfig, *, repair: bool = False, quiet: bool = False,
             stop_after: int | None = None, cluster: ClusterConfig | None = None) -> Dataset:
    """Simulate a dataset into folder ``out``, resuming from the first missing chunk.

    One writer per dataset folder: the call holds ``out``'s lock
    (:func:`rfmitsuba.core.folder_lock.folder_lock`) throughout, so a second ``generate`` into
    ``out`` is refused at once, naming the first one's pid, instead of simulating the same states
    twice. A folder this call created is removed again when the call fails before it wrote
    ``meta.json``.

    Args:
        out: dataset folder (created; an existing one must hold the same configuration).
        cfg: :class:`GenerateConfig`.
        repair: re-simulate chunks that fail the full (sha256) check instead of raising.
        quiet: no progress bar.
        stop_after: simulate at most this many states, then return (for tests of resuming).
        cluster: where the states are simulated (:mod:`rfmitsuba.core.cluster`; default here,
            one after another). On Dask the missing states are split into runs of consecutive
            states, about two per worker, each simulated by :func:`simulate_states` in a worker
            with its own ray tracer; every state's chunk is bit-identical to a serial run's.
    Returns:
        The dataset, opened (only if complete; else the partially written one unchecked).
    Raises:
        DatasetError: ``out`` holds another configuration (the differing key is named) or a
            damaged chunk (named) and ``repair`` is off.
        PlacementError: bad positions; SceneError: unknown or broken scene; JobsFailed (a
            RunError): on a cluster, runs of states failed (named; the written chunks are kept).
    """
    from ..core.folder_lock import writer

    root = Path(out)
    with writer(root, what="generate", keep=lambda f: (f / "meta.json").exists()):
        return _generate_locked(root, cfg, repair=repair, quiet=quiet, stop_after=stop_after, cluster=cluster)


def _generate_locked(out: Path, cfg: GenerateConfig, *, repair: bool, quiet: bool, stop_after: int | None,
                     cluster: ClusterConfig | None) -> Dataset:
    """:func:`generate`'s work, with ``out``'s lock held."""
    import time


    if cfg.task not in ("rx", "tx"):
        raise ConfigError(f"task must be 'rx' or 'tx', got {cfg.task!r}")
    if cfg.positions < 1 or cfg.person_positions < 0:
        raise ConfigError(f"need positions >= 1 and person_positions >= 0, got {cfg.positions}, {cfg.person_positions}")
    if cfg.people < 1:
        raise ConfigError(f"people must be >= 1, got {cfg.people}")
    if cfg.material not in person.PERTURBER_MATERIALS:
        raise ConfigError(f"unknown material {cfg.material!r}; known: {', '.join(person.PERTURBER_MATERIALS)}")
    if cfg.array not in ARRAYS:
        raise ConfigError(f"array must be one of {', '.join(ARRAYS)}, got {cfg.array!r}")
    if cfg.array == "exact" and cfg.positions > EXACT_MAX_POSITIONS:
        raise ConfigError(f"array 'exact' traces each of the 16 elements as its own antenna (16x the receivers "
                          f"of a synthetic-array solve); it is meant for a subset of positions: got "
                          f"{cfg.positions}, at most {EXACT_MAX_POSITIONS}")
    t_start = time.perf_counter()
    xml = resolve_scene(cfg.scene)
    geom = RoomGeometry.from_xml(xml)
    solver = cfg.solver if cfg.solver is not None else default_solver(geom)
    if isinstance(solver, dict):
        solver = _config.from_dict(SolverConfig, solver)
    solver.check()
    fixed = geom.corner(inset=cfg.corner_inset, height=cfg.corner_height)
    if cfg.person_positions:
        walk = person.walk(geom, n=cfg.person_positions, duration_s=cfg.walk_duration_s, seed=cfg.seed)
        walk_pos, walk_head = np.asarray(walk.positions), np.asarray(walk.headings)
    else:
        walk_pos, walk_head = np.zeros((0, 3)), np.zeros(0)
    others_pos, others_head = other_walks(geom, walk_pos, people=cfg.people, n=len(walk_pos),
                                          duration_s=cfg.walk_duration_s, seed=cfg.seed)
    body_r = person.radius() + cfg.person_margin
    ant = place_antennas(geom, cfg.positions, rng=np.random.default_rng([cfg.seed, 1]), z_range=cfg.z_range,
                         clearance=cfg.clearance, walk_positions=np.concatenate([walk_pos, others_pos.reshape(-1, 3)]),
                         body_radius=body_r,
                         body_height=person.HEIGHT + 0.1, avoid=fixed)
    geom.check_points(ant, what="antenna")
    ant32 = ant.astype(np.float32)
    plugin, params = person.PERTURBER_MATERIALS[cfg.material]
    record = {k: v for k, v in _config.to_dict(_replace(cfg, solver=None)).items() if k != "solver"}
    if cfg.array == "synthetic":  # the default, and what every dataset made before the option holds
        del record["array"]
    if cfg.people == 1:           # the same: one person, as every dataset made before the option
        del record["people"]
    extra = {
        "scene": _scene_record(xml),
        "generate": record,
        "solver": _config.to_dict(solver),
        "seeds": {"antenna_positions": [cfg.seed, 1], "walk": cfg.seed, "split": cfg.seed, "solver": solver.seed},
        "person": {"headings_rad": walk_head.tolist(), "height_m": person.HEIGHT, "width_m": person.WIDTH,
                  "material": cfg.material, "material_plugin": plugin, "material_params": params,
                  "placement": "feet at person_positions, facing headings_rad (about +z)"},
        **({"other_people": {"positions": others_pos.tolist(), "headings_rad": others_head.tolist(),
                             "placement": "frame-major: [frame][person 2..P] feet positions [m] and headings"}}
           if cfg.people > 1 else {}),
        "fixed_device": "isotropic TX" if cfg.task == "rx" else "4x4 array",
        "moving_device": "4x4 array" if cfg.task == "rx" else "isotropic TX",
        "reciprocity": "one solve: TX at fixed_pos, isotropic RX at each antenna position; "
                       + ("arrival directions at the antenna positions" if cfg.task == "rx" else
                          "departure directions at fixed_pos") + " give the array channel"
                       if cfg.array == "synthetic" else
                       ("one isotropic RX per array element at each antenna position" if cfg.task == "rx" else
                        "the TX moved through the 16 array elements at fixed_pos, one solve each")
                       + "; each element's channel is the sum of its own paths (generate.array = 'exact')",
        "versions": versions(),
    }
    meta = base_meta(task=cfg.task, frequency_hz=cfg.frequency_hz, num_antennas=cfg.positions,
                     person_positions=walk_pos, fixed_pos=fixed, extra=extra)
    split = make_split(cfg.positions, cfg.person_positions, seed=cfg.seed)
    root = prepare_folder(out, meta, antenna_pos=ant32, split=split)
    remove_stale_tmp(root)
    S = 1 + cfg.person_positions
    todo = []
    for s in range(S):
        if not (root / "chunks" / chunk_name(s)).exists():
            todo.append(s)
            continue
        try:
            check_chunk(root, s, cfg.positions, full=True)     # sha256 of every finished chunk on resume
        except DatasetError as e:
            if not repair:
                raise DatasetError(f"{e}; run generate with --repair to simulate it again") from None
            todo.append(s)
    if stop_after is not None:
        todo = todo[:stop_after]
    job = StatesJob(root=root, xml=xml, task=cfg.task, frequency_hz=cfg.frequency_hz, material=cfg.material,
                    scattering_coefficient=cfg.scattering_coefficient, solver=solver, fixed_pos=fixed,
                    antenna_pos=ant32, walk_positions=walk_pos, walk_headings=walk_head, array=cfg.array,
                    other_positions=others_pos, other_headings=others_head)
    cluster = cluster or ClusterConfig()
    if cluster.serial or not todo:
        timing = simulate_states(job, todo, quiet=quiet)
    else:
        timing = _simulate_on_cluster(job, todo, cluster=cluster, quiet=quiet)
    timing["total_s"] = time.perf_counter() - t_start
    # on a cluster the states ran side by side: the share is of the workers' busy time
    busy = timing["busy_s"] if "workers" in timing else timing["total_s"]
    timing["outside_solver_share"] = 1 - timing["solver_s"] / busy if busy else 0.0
    _append_timing(root, timing)
    missing = [s for s in range(S) if not (root / "chunks" / chunk_name(s)).exists()]
    return Dataset(root, check=not missing)


@dataclass(frozen=True)
class StatesJob:
    """Everything a process needs to simulate states of one dataset into its folder (plain data).

    Positions are metres: ``fixed_pos`` float64 [3] (the fixed device), ``antenna_pos``
    float32 [A, 3] (as stored), ``walk_positions`` float64 [H, 3] (feet of the person at states
    1..H), ``walk_headings`` float64 [H] (radians about +z).
    """

    root: Path
    xml: Path
    task: str
    frequency_hz: float
    material: str
    scattering_coefficient: float
    solver: SolverConfig
    fixed_pos: np.ndarray
    antenna_pos: np.ndarray
    walk_positions: np.ndarray
    walk_headings: np.ndarray
    #: how the element channels are traced (:data:`rfmitsuba.sim.simulate.ARRAYS`)
    array: str = "synthetic"
    #: float64 [H, P - 1, 3] / [H, P - 1]: the other people's feet [m] and headings [rad] (none: one person)
    other_positions: np.ndarray | None = None
    other_headings: np.ndarray | None = None

    def bodies(self, s: int):
        """The mesh of every person at state ``s`` >= 1, as one mesh (trimesh)."""
        meshes = [person.person_mesh(self.walk_positions[s - 1], float(self.walk_headings[s - 1]))]
        if self.other_positions is not None:
            for p, h in zip(self.other_positions[s - 1], self.other_headings[s - 1]):
                meshes.append(person.person_mesh(p, float(h)))
        if len(meshes) == 1:
            return meshes[0]
        import trimesh

        return trimesh.util.concatenate(meshes)


#: images per Bartlett block of a state's PAS (:func:`simulate_states`): 33 MB, which the write
#: copies out while much of it is still in the cache
PAS_BLOCK = 256


def simulate_states(job: StatesJob, states: list[int], *, quiet: bool = True) -> dict:
    """Ray-trace ``states`` (0 = empty room, s = walk position s) of ``job`` and write their chunks.

    A state's chunk does not depend on the states simulated before it in the same process
    (:mod:`rfmitsuba.sim.simulate`), so any split of the states over processes gives the same files.

    Returns:
        {"states": number simulated, "solver_s", "pas_s", "write_s": seconds in the ray
        tracer, the Bartlett PAS and writing, "busy_s": wall seconds of this call}.
    """
    import time

    t_start = time.perf_counter()
    timing = {"states": len(states), "solver_s": 0.0, "pas_s": 0.0, "write_s": 0.0}
    if states:
        sim = Simulator(job.xml, fixed_pos=job.fixed_pos, frequency_hz=job.frequency_hz, solver=job.solver)
        if job.solver.diffuse_reflection:
            sim.set_scattering(job.scattering_coefficient)
        # positions as float32, the precision they are stored with
        sim.set_positions(job.antenna_pos.astype(np.float64))
        faces = None
        # one image buffer of PAS_BLOCK images for every block of every state, written out
        # before the next is made: fresh pages cost more than the beamforming
        # (rfmitsuba.rf.bartlett_ref.bartlett), and a state is never held whole (7500 positions:
        # 972 MB of images, 2.4 s of Bartlett into fresh memory)
        images = np.empty((min(PAS_BLOCK, len(job.antenna_pos)), *PAS_SHAPE), np.float32)

        def blocks(h):
            for k in range(0, len(h), len(images)):
                t = time.perf_counter()
                part = h[k:k + len(images)]
                img = _pas.bartlett(part, frequency_hz=job.frequency_hz, out=images[:len(part)])
                timing["pas_s"] += time.perf_counter() - t
                yield img

        with progress.bar(len(states), desc=f"{job.xml.stem} {job.task}", unit="state", quiet=quiet) as pb:
            for s in states:
                if s == 0:
                    sim.set_person(None)
                else:
                    mesh = job.bodies(s)
                    if faces is None:
                        faces = np.asarray(job.bodies(1).faces)
                        first = np.asarray(job.bodies(1).vertices)
                        sim.set_person(first, faces, material=person.radio_material(job.material,
                                                                                  name=f"rfm-person-{job.material}"))
                    sim.set_person(np.asarray(mesh.vertices))
                t0 = sim.timing.solver_s
                h = sim.channels(job.task, array=job.array)
                timing["solver_s"] += sim.timing.solver_s - t0
                t1, before = time.perf_counter(), timing["pas_s"]
                write_chunk(job.root, s, pas_blocks=blocks(h), channel=h)   # beamforms as it writes
                timing["write_s"] += time.perf_counter() - t1 - (timing["pas_s"] - before)
                pb.update(1)
    timing["busy_s"] = time.perf_counter() - t_start
    return timing


def _simulate_on_cluster(job: StatesJob, todo: list[int], *, cluster: ClusterConfig, quiet: bool) -> dict:
    """:func:`simulate_states` of ``todo`` on Dask: runs of consecutive states, about two per
    worker (each run pays for one scene load); timings summed, ``workers`` recorded."""
    job = dataclasses.replace(job, root=Path(job.root).resolve(), xml=Path(job.xml).resolve())
    with session(cluster) as s:
        n = s.num_workers
        parts = [p.tolist() for p in np.array_split(np.asarray(todo), min(len(todo), 2 * n))]
        tasks = [Task(f"states {p[0]}-{p[-1]}", simulate_states, (job, p)) for p in parts]
        res = s.run(tasks, desc=f"{job.xml.stem} {job.task}", unit="run", quiet=quiet)
    timing = {k: sum(r[k] for r in res.values()) for k in ("states", "solver_s", "pas_s", "write_s", "busy_s")}
    timing["workers"] = n
    return timing


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
    _write_meta_json(f, runs)
