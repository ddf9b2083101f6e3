"""Reproduce the paper's tables: datasets, jobs, resumable runs, the Markdown report.

:func:`reproduce` runs an :class:`ExperimentConfig` into an output folder::

    OUT/experiment.toml     the configuration (another configuration here -> RunError)
    OUT/data/<dataset>/     generated datasets (unless --data points elsewhere)
    OUT/jobs/<dataset>/<method>_s<seed>[_snr<dB>][_n<positions>]/
        job.toml            what the job is (checked on resume)
        train/ | stage2/    Trainer run folders (resumable from their checkpoints)
        metrics.json        both evaluations, written atomically, then
        DONE                the done-marker: finished jobs are skipped
    OUT/report.md, OUT/speed_accuracy.png, OUT/results.json

Every job is one (dataset, method, seed[, SNR][, training positions]). Ours reuses the
Baseline job of the same dataset, seed and variant as its Stage 1 (so Baseline *is* Ours'
first stage, as in the paper). Tables (:data:`TABLES`): main, two_stage, perturbation,
material, large_room, positions, noise. Sizes (:data:`SIZES`): ``tiny`` (synthetic data,
no Sionna; tests), ``quick`` (Sionna, 36 positions x 7 states; minutes on 2 cores) and
``full`` (the paper's 900 positions x 35 walk positions).
"""
from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field as dc_field
from pathlib import Path

import numpy as np

from . import config as C
from .atomic import numpy_default, write_json
from .errors import ConfigError, RunError

TABLES = ("main", "two_stage", "perturbation", "material", "large_room", "positions", "noise")


@dataclass
class DataSize:
    """Dataset sizes: antenna positions, walk (human) positions, ray samples per source (0 = the
    dataset module's default for the room)."""

    positions: int = 900
    human_positions: int = 35
    samples_per_src: int = 0


@dataclass
class TrainSize:
    """Training sizes shared by every method (steps, image downsampling, Gaussians) and the model
    family: "coherent" (image sources read out by Bartlett, :mod:`rfmitsuba.coherent`; trains at
    full resolution whatever ``downsample`` says; needs a scene, so Sionna data only) or "splat"
    (Gaussian splatting, WRF-GS+ style)."""

    model: str = "coherent"
    stage1_iterations: int = 3000
    stage2_iterations: int = 1000
    downsample: int = 2
    batch_views: int = 4
    num_gaussians: int = 3000
    max_gaussians: int = 20000
    human_gaussians: int = 300
    val_every: int = 250
    density: bool = True


@dataclass
class ExperimentConfig:
    """What :func:`reproduce` runs.

    size: label ("tiny", "quick", "full"); source: "sionna" (rfmitsuba.dataset.generate) or
    "synthetic" (rfmitsuba.synthetic, no Sionna); seeds: training seeds (>= 3 for the report's
    mean +- std); rooms / tasks: of the main table (the first room and task are used by the
    ablations); materials: perturber materials; large_room: scene of the large-room table ("" =
    skip); snr_db: noise levels of the noise table; position_counts: training antenna positions of
    the positions table; tables: which tables to run.
    """

    size: str = "full"
    source: str = "sionna"
    seeds: list[int] = dc_field(default_factory=lambda: [0, 1, 2])
    data: DataSize = dc_field(default_factory=DataSize)
    train: TrainSize = dc_field(default_factory=TrainSize)
    rooms: list[str] = dc_field(default_factory=lambda: ["bedroom", "living_room", "dining_room"])
    tasks: list[str] = dc_field(default_factory=lambda: ["rx", "tx"])
    materials: list[str] = dc_field(default_factory=lambda: ["tissue", "metal", "concrete"])
    large_room: str = "large_room"
    snr_db: list[float] = dc_field(default_factory=lambda: [20.0, 10.0, 0.0])
    position_counts: list[int] = dc_field(default_factory=lambda: [180, 360])
    tables: list[str] = dc_field(default_factory=lambda: list(TABLES))

    def __post_init__(self) -> None:
        if self.source not in ("sionna", "synthetic"):
            raise ConfigError(f"ExperimentConfig.source must be 'sionna' or 'synthetic', got {self.source!r}")
        bad = [t for t in self.tables if t not in TABLES]
        if bad:
            raise ConfigError(f"ExperimentConfig.tables: unknown {bad}; known: {list(TABLES)}")
        if not self.seeds or not self.rooms or not self.tasks:
            raise ConfigError("ExperimentConfig: seeds, rooms and tasks must not be empty")
        if any(t not in ("rx", "tx") for t in self.tasks):
            raise ConfigError(f"ExperimentConfig.tasks must be 'rx' / 'tx', got {self.tasks}")
        if self.train.model not in ("splat", "coherent"):
            raise ConfigError(f"ExperimentConfig.train.model must be 'splat' or 'coherent', got {self.train.model!r}")
        if self.train.model == "coherent" and self.source == "synthetic":
            raise ConfigError("train.model = 'coherent' needs Sionna data with a scene; synthetic data has none "
                              "(use train.model = 'splat')")


SIZES = {
    "tiny": ExperimentConfig(
        size="tiny", source="synthetic", seeds=[0, 1, 2], data=DataSize(positions=25, human_positions=6),
        train=TrainSize(model="splat", stage1_iterations=30, stage2_iterations=30, downsample=10, batch_views=4,
                        num_gaussians=120, max_gaussians=400, human_gaussians=24, val_every=30, density=False),
        rooms=["bedroom"], tasks=["rx"], materials=["tissue"], large_room="", snr_db=[10.0],
        position_counts=[10], tables=["main", "two_stage", "perturbation", "positions", "noise"]),
    "quick": ExperimentConfig(
        size="quick", seeds=[0, 1, 2], data=DataSize(positions=36, human_positions=6, samples_per_src=20000),
        train=TrainSize(stage1_iterations=100, stage2_iterations=100, downsample=6, batch_views=4,
                        num_gaussians=400, max_gaussians=1000, human_gaussians=48, val_every=50, density=False),
        snr_db=[10.0], position_counts=[12]),
    "full": ExperimentConfig(),
}


def size_config(name: str) -> ExperimentConfig:
    """A copy of the named size's configuration (ConfigError on an unknown name)."""
    if name not in SIZES:
        raise ConfigError(f"unknown size {name!r}; known: {', '.join(SIZES)}")
    return C.from_dict(ExperimentConfig, C.to_dict(SIZES[name]))


# =========================================================================== jobs

@dataclass(frozen=True)
class DatasetSpec:
    """One dataset: scene, task and perturber material."""

    scene: str
    task: str
    material: str = "tissue"

    @property
    def key(self) -> str:
        return f"{self.scene}_{self.task}_{self.material}"


@dataclass(frozen=True)
class Job:
    """One training + evaluation: dataset, method, seed, noise SNR (None = clean), training
    antenna positions (0 = all)."""

    dataset: DatasetSpec
    method: str
    seed: int
    snr_db: float | None = None
    positions: int = 0

    @property
    def key(self) -> str:
        k = f"{self.method}_s{self.seed}"
        if self.snr_db is not None:
            k += f"_snr{self.snr_db:g}"
        if self.positions:
            k += f"_n{self.positions}"
        return k

    def folder(self, out: Path) -> Path:
        return Path(out) / "jobs" / self.dataset.key / self.key

    def stage1_job(self) -> "Job":
        return dataclasses.replace(self, method="baseline")

    def record(self) -> dict:
        return {"dataset": self.dataset.key, "scene": self.dataset.scene, "task": self.dataset.task,
                "material": self.dataset.material, "method": self.method, "seed": self.seed,
                "snr_db": "none" if self.snr_db is None else float(self.snr_db), "positions": self.positions}


def table_jobs(cfg: ExperimentConfig) -> dict[str, list[Job]]:
    """The jobs of every configured table (a job may serve several tables)."""
    room, task = cfg.rooms[0], cfg.tasks[0]
    ref = DatasetSpec(room, task)
    out: dict[str, list[Job]] = {}
    for t in cfg.tables:
        jobs: list[Job] = []
        for seed in cfg.seeds:
            if t == "main":
                jobs += [Job(DatasetSpec(r, k), m, seed) for r in cfg.rooms for k in cfg.tasks
                         for m in ("baseline", "end_to_end", "ours")]
            elif t == "two_stage":
                jobs += [Job(ref, m, seed) for m in ("baseline", "end_to_end", "continued", "ours")]
            elif t == "perturbation":
                jobs += [Job(ref, m, seed) for m in ("baseline", "duplicated", "baseline_human", "ours")]
            elif t == "material":
                jobs += [Job(DatasetSpec(room, task, mat), m, seed) for mat in cfg.materials for m in ("baseline", "ours")]
            elif t == "large_room" and cfg.large_room:
                jobs += [Job(DatasetSpec(cfg.large_room, "rx"), m, seed) for m in ("baseline", "ours")]
                jobs += [Job(DatasetSpec(room, "rx"), m, seed) for m in ("baseline", "ours")]
            elif t == "positions":
                for n in list(cfg.position_counts) + [0]:
                    jobs += [Job(ref, m, seed, positions=n) for m in ("baseline", "ours")]
            elif t == "noise":
                for snr in [None] + list(cfg.snr_db):
                    jobs += [Job(ref, m, seed, snr_db=snr) for m in ("baseline", "end_to_end", "ours")]
        out[t] = jobs
    return out


def all_jobs(cfg: ExperimentConfig) -> list[Job]:
    """Every job once, each Ours after the Baseline it builds on."""
    seen: dict[str, Job] = {}
    for jobs in table_jobs(cfg).values():
        for j in jobs:
            if j.method == "ours":
                b = j.stage1_job()
                seen.setdefault(f"{b.dataset.key}/{b.key}", b)
            seen.setdefault(f"{j.dataset.key}/{j.key}", j)
    return list(seen.values())


def method_config(cfg: ExperimentConfig):
    """The :class:`rfmitsuba.methods.MethodConfig` of an experiment's training sizes."""
    from .field import FieldConfig
    from .density import DensityConfig
    from .human_field import HumanConfig
    from .methods import MethodConfig
    from .train import TrainConfig

    t = cfg.train
    s1 = TrainConfig(iterations=t.stage1_iterations, batch_views=t.batch_views, model=t.model,
                     downsample=1 if t.model == "coherent" else t.downsample,
                     val_every=t.val_every, checkpoint_every=t.val_every, log_every=max(1, t.val_every // 4),
                     field=FieldConfig(init="random" if cfg.source == "synthetic" else "mesh",
                                       num_gaussians=t.num_gaussians),
                     density=DensityConfig(enabled=t.density, max_gaussians=t.max_gaussians,
                                           start=max(1, t.stage1_iterations // 4),
                                           every=max(1, t.stage1_iterations // 8)))
    return MethodConfig(stage1=s1, stage2_iterations=t.stage2_iterations,
                        human=HumanConfig(num_gaussians=t.human_gaussians))


# =========================================================================== datasets

def dataset_path(spec: DatasetSpec, cfg: ExperimentConfig, data_dir: Path) -> Path:
    d = cfg.data
    return Path(data_dir) / f"{spec.key}_{cfg.source}_{d.positions}x{d.human_positions}"


def ensure_dataset(spec: DatasetSpec, cfg: ExperimentConfig, data_dir: Path, *, quiet: bool = True) -> Path:
    """Generate the dataset of ``spec`` unless it is complete (resumes a partial one)."""
    path = dataset_path(spec, cfg, data_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    d = cfg.data
    if cfg.source == "synthetic":
        if not (path / "meta.json").is_file():
            from . import synthetic

            seed = {"tissue": 0, "metal": 1, "concrete": 2}.get(spec.material, 3) + (10 if spec.task == "tx" else 0)
            synthetic.make_dataset(path, antennas=d.positions, humans=d.human_positions, seed=seed, task=spec.task)
        return path
    from . import dataset as D
    from .simulate import SolverConfig

    solver = SolverConfig(samples_per_src=d.samples_per_src) if d.samples_per_src else None
    gcfg = D.GenerateConfig(scene=spec.scene, task=spec.task, positions=d.positions, human_positions=d.human_positions,
                            material=spec.material, seed=data_seed(spec.scene, d.human_positions), solver=solver)
    D.generate(path, gcfg, quiet=quiet)
    return path


def data_seed(scene: str, human_positions: int, *, tries: int = 8) -> int:
    """The first seed in 0..tries-1 for which :func:`rfmitsuba.human.walk` finds a clear walk of
    ``human_positions`` steps in ``scene`` (the walk sampler gives up on some seeds in small rooms).

    Raises:
        PlacementError: no seed works.
    """
    from . import human
    from .dataset import resolve_scene
    from .errors import PlacementError, RfmError
    from .geometry import RoomGeometry

    if human_positions < 1:
        return 0
    geom = RoomGeometry.from_xml(resolve_scene(scene))
    for s in range(tries):
        try:
            human.walk(geom, n=human_positions, seed=s)
            return s
        except RfmError:
            continue
    raise PlacementError(f"no clear walk of {human_positions} positions in {scene} for seeds 0..{tries - 1}")


# =========================================================================== running

def _check_experiment(out: Path, cfg: ExperimentConfig) -> None:
    from .train import config_diff

    f = out / "experiment.toml"
    if f.is_file():
        have = C.to_dict(C.load(ExperimentConfig, f))
        diff = config_diff(have, C.to_dict(cfg))
        if diff:
            raise RunError(f"output folder {out} holds another experiment configuration: {'; '.join(diff)}. "
                           "Use another --out (nothing was changed)")
    elif out.is_dir() and (out / "jobs").exists():
        raise RunError(f"{out} holds jobs but no experiment.toml; not an experiment folder (nothing was changed)")


def run_job(job: Job, out: Path, cfg: ExperimentConfig, data_dir: Path, *, quiet: bool = True,
            reevaluate: bool = False) -> dict:
    """Train and evaluate one job by :func:`rfmitsuba.methods.run_job` (skipped when done, or
    evaluated again with ``reevaluate``); returns its metrics.

    Raises:
        RunError: the job folder holds a job of another configuration (``job.json`` differs).
    """
    from .methods import config_dict, run_job as methods_run_job
    from .train import config_diff

    jd = job.folder(out)
    mcfg = method_config(cfg)
    if not (jd / "DONE").is_file():
        want = {"job": job.record(), "method_config": config_dict(mcfg)}
        jt = jd / "job.json"
        if jt.is_file():
            diff = config_diff(json.loads(jt.read_text()), json.loads(json.dumps(want)))
            if diff:
                raise RunError(f"job folder {jd} belongs to another configuration: {'; '.join(diff)} "
                               "(nothing was changed)")
        jd.mkdir(parents=True, exist_ok=True)
        _write_json(jt, want)
    stage1 = None
    if job.method == "ours":
        b = job.stage1_job()
        run_job(b, out, cfg, data_dir, quiet=quiet)
        stage1 = b.folder(out) / "train"
    return methods_run_job(job.method, dataset_path(job.dataset, cfg, data_dir), jd, mcfg=mcfg, seed=job.seed,
                           record={"job": job.record()}, noise_snr_db=job.snr_db, train_antennas=job.positions,
                           stage1_dir=stage1, reevaluate=reevaluate, quiet=quiet)


class Stopped(RunError):
    """Raised by :func:`reproduce` after ``stop_after`` jobs (a simulated kill, for tests)."""


def reproduce(out: str | Path, cfg: ExperimentConfig, *, data_dir: str | Path | None = None,
              stop_after: int | None = None, reevaluate: bool = False, quiet: bool = False) -> Path:
    """Generate what is missing, run every job not yet done, write the report.

    Args:
        out: output folder (created; resumes an interrupted run of the same configuration).
        cfg: the experiment.
        data_dir: where datasets live (default ``out/data``); existing complete ones are reused.
        stop_after: raise :class:`Stopped` after this many newly finished jobs (tests).
        reevaluate: evaluate finished jobs again (after the evaluation changed; no retraining).
        quiet: no progress bars.

    Returns:
        path of ``report.md``.

    Raises:
        RunError: ``out`` holds another configuration (the differing key is named).
    """
    from .progress import bar

    out = Path(out)
    _check_experiment(out, cfg)
    out.mkdir(parents=True, exist_ok=True)
    if not (out / "experiment.toml").is_file():
        C.save(cfg, out / "experiment.toml")
    data_dir = Path(data_dir) if data_dir else out / "data"
    t_start = time.perf_counter()
    jobs = all_jobs(cfg)
    specs = list(dict.fromkeys(j.dataset for j in jobs))
    with bar(total=len(specs), desc="datasets", unit="dataset", quiet=quiet) as pb:
        for spec in specs:
            ensure_dataset(spec, cfg, data_dir, quiet=True)
            pb.update(1)
    done_new = 0
    results = {}
    with bar(total=len(jobs), desc="jobs", unit="job", quiet=quiet) as pb:
        for j in jobs:
            was_done = (j.folder(out) / "DONE").is_file()
            results[f"{j.dataset.key}/{j.key}"] = run_job(j, out, cfg, data_dir, quiet=True, reevaluate=reevaluate)
            pb.update(1)
            if not was_done:
                done_new += 1
                if stop_after is not None and done_new >= stop_after:
                    raise Stopped(f"stopped after {done_new} jobs (stop_after); run again to resume")
    wall = time.perf_counter() - t_start
    _write_json(out / "results.json", results)
    from .report import write_report

    return write_report(out, cfg, results, wall_s=wall)


def _write_json(path: Path, obj) -> None:
    write_json(path, obj, allow_nan=True, default=numpy_default)


def mean_std(values: list[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (0 for one value; NaN for none)."""
    v = [x for x in values if x is not None and math.isfinite(x)]
    if not v:
        return float("nan"), float("nan")
    return float(np.mean(v)), float(np.std(v, ddof=1)) if len(v) > 1 else 0.0
