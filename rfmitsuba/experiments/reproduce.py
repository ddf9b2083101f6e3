"""Reproduce the paper's tables: datasets, jobs, resumable runs, the Markdown report.

:func:`reproduce` runs an :class:`ExperimentConfig` into an output folder::

    OUT/experiment.toml     the configuration; a later run into OUT must keep its size, source,
                            data and train (else RunError) and may add seeds, rooms, tables, ...
    OUT/data/<dataset>/     generated datasets (unless --data points elsewhere)
    OUT/jobs/<dataset>/<method>_s<seed>[_snr<dB>][_n<positions>][_grid][_w<walk>][_on_<dataset>]/
        job.json            what the job is (checked on resume)
        train/ | stage2/    Trainer run folders (resumable from their checkpoints)
        metrics.json        both evaluations, written atomically, then
        DONE                the done-marker: finished jobs are skipped
    OUT/floors/             the evaluation floors, once per dataset (rfmitsuba.eval.floor_cache)
    OUT/truth/<room>_<task>/  the truth checks beside the main table (ExperimentConfig.truth_positions;
                            rfmitsuba.experiments.truth): synthetic against exact per-element truth
    OUT/report.md, OUT/speed_accuracy.png, OUT/results.json
    OUT/runs.jsonl          one line per run: wall time, jobs run, and why it stopped early if it did
                            (an error, Ctrl-C, SIGTERM); kept current while a run lasts, so a run
                            killed outright (SIGKILL) keeps its time to within a minute; the report
                            sums them

Every job is one (dataset, method, seed[, SNR][, training positions]). Ours reuses the
Baseline job of the same dataset, seed and variant as its Stage 1 (so Baseline *is* Ours'
first stage, as in the paper). Tables (:data:`rfmitsuba.experiments.paper_tables.TABLES`):
main, two_stage, perturbation, material, large_room, positions, noise, rx_count,
third_stage, data_scarce (only when named); one dataset's jobs run in a row. :mod:`rfmitsuba.experiments.plan` says what is
left and how long it should take, before anything runs. Sizes (:data:`SIZES`): ``tiny`` (synthetic data,
no Sionna; tests), ``quick`` (Sionna, 36 positions x 7 states; minutes on 2 cores), ``medium``
(300 positions x 36 states) and ``full`` (the paper's 900 positions x 35 walk positions).
"""
from __future__ import annotations

import json
import os
import shutil
import threading
import time
from pathlib import Path

from ..core import config as C
from ..core.atomic import write_json_with_numpy, write_text
from ..core.cluster import ClusterConfig, Task, run_tasks
from ..core.errors import ConfigError, PlacementError, RfmError, RunError
from ..core.folder_lock import folder_lock
from ..core.interrupt import sigterm_interrupts
from ..core.legacy_names import current_keys, current_name
from ..data.store import resolve_scene
from ..train.config import config_diff
from .job import Job
from .methods import FLOORS_FOLDER, MethodConfig, config_dict, prior_kwargs, run_job
from .paper_tables import all_jobs
from .report import RUNS_FILE, write_report
from .sizes import DatasetSpec, DataSize, ExperimentConfig, method_config


def dataset_shape(spec: DatasetSpec, cfg: ExperimentConfig) -> tuple[int, int]:
    """(antenna positions, walk positions) of the dataset of ``spec`` at the size of ``cfg``: an
    empty-room dataset's own positions and no walk, a long-walk dataset's own walk, else the size's."""
    d = cfg.data
    if spec.static_positions:
        return spec.static_positions, 0
    return d.positions, spec.walk_positions or d.person_positions


#: the walk's own pace: positions per minute (the paper's 35 positions in a minute)
WALK_PER_MINUTE = 35


def walk_duration_s(spec: DatasetSpec, cfg: ExperimentConfig) -> float:
    """How long the walk of ``spec``'s dataset lasts [s]: a long-walk dataset
    (:attr:`DatasetSpec.walk_positions`) walks at :data:`WALK_PER_MINUTE`, every other one 60 s."""
    return 60.0 * spec.walk_positions / WALK_PER_MINUTE if spec.walk_positions else 60.0


def dataset_path(spec: DatasetSpec, cfg: ExperimentConfig, data_dir: Path) -> Path:
    """Where the dataset of ``spec`` lives: ``data_dir/<key>_<source>_<positions>x<walk positions>``."""
    positions, walk = dataset_shape(spec, cfg)
    return Path(data_dir) / f"{spec.key}_{cfg.source}_{positions}x{walk}"


#: position seed of the Rx-count table's empty-room datasets (added to the main dataset's seed):
#: other positions in the same room
STATIC_SEED_OFFSET = 1000


def ensure_dataset(spec: DatasetSpec, cfg: ExperimentConfig, data_dir: Path, *, quiet: bool = True) -> Path:
    """Generate the dataset of ``spec`` unless it is complete (resumes a partial one)."""
    path = dataset_path(spec, cfg, data_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    d = cfg.data
    positions, walk = dataset_shape(spec, cfg)
    if cfg.source == "synthetic":
        if not (path / "meta.json").is_file():
            from ..sim import synthetic

            # the seed draws the synthetic scene first, so the static dataset keeps it and differs
            # in its antenna positions by their count (and in the 2 walk states, which it ignores)
            seed = {"tissue": 0, "metal": 1, "concrete": 2}.get(spec.material, 3) + (10 if spec.task == "tx" else 0)
            synthetic.make_dataset(path, antennas=positions, people=max(walk, 2), seed=seed, task=spec.task)
        return path
    from ..sim import generate as gen

    solver = solver_config(spec.scene, d)
    duration = walk_duration_s(spec, cfg)
    # an empty-room dataset (the Rx-count table's extra positions) is seeded by the size's walk
    seed = (data_seed(spec.scene, walk if spec.walk_positions else d.person_positions, duration_s=duration)
            + (STATIC_SEED_OFFSET if spec.static_positions else 0))
    gcfg = gen.GenerateConfig(scene=spec.scene, task=spec.task, positions=positions, person_positions=walk,
                              material=spec.material, seed=seed, solver=solver, walk_duration_s=duration)
    gen.generate(path, gcfg, quiet=quiet)
    return path


def solver_config(scene: str, data: DataSize):
    """The ``SolverConfig`` of a dataset of ``scene`` at size ``data``: ``data.samples_per_src`` ray
    samples, else ``data.samples_scale`` times the room's default (at least 1000); None where that
    is the room's default unchanged (:func:`rfmitsuba.sim.generate.default_solver`)."""
    from ..sim import generate as gen
    from ..sim.geometry import RoomGeometry
    from ..sim.simulate import SolverConfig

    if data.samples_per_src:
        return SolverConfig(samples_per_src=data.samples_per_src)
    if data.samples_scale == 1.0:
        return None
    base = gen.default_solver(RoomGeometry.from_xml(resolve_scene(scene)))
    return SolverConfig(samples_per_src=max(int(round(base.samples_per_src * data.samples_scale)), 1000))


def truth_checks(cfg: ExperimentConfig) -> list[tuple[str, str]]:
    """The (room, task) pairs whose truth uncertainty a reproduction of ``cfg`` checks: every room
    x task of the main table, where the data come from Sionna and ``cfg.truth_positions`` > 0."""
    if cfg.source != "sionna" or not cfg.truth_positions or "main" not in cfg.tables:
        return []
    return [(r, k) for r in cfg.rooms for k in cfg.tasks]


def ensure_truth(scene: str, task: str, cfg: ExperimentConfig, out: Path, *, quiet: bool = True) -> dict:
    """Run (or resume) the truth check of ``scene`` and ``task`` into its folder of ``out``
    (:func:`rfmitsuba.experiments.truth.truth_folder`): ``cfg.truth_positions`` positions of the
    empty room traced with the synthetic and the exact array, at the datasets' ray samples
    (:func:`solver_config`). Returns the PAS SSIM statistics of synthetic against exact."""
    from .truth import TruthConfig, truth_folder, truth_uncertainty

    solver = solver_config(scene, cfg.data)
    tc = TruthConfig(scene=scene, task=task, positions=cfg.truth_positions,
                     samples=solver.samples_per_src if solver is not None else None)
    return truth_uncertainty(truth_folder(out, scene, task), tc, quiet=quiet)["stats"]["ssim"]


def data_seed(scene: str, person_positions: int, *, tries: int = 8, duration_s: float = 60.0) -> int:
    """The first seed in 0..tries-1 for which :func:`rfmitsuba.sim.person.walk` finds a clear walk of
    ``person_positions`` steps over ``duration_s`` seconds in ``scene`` (the walk sampler gives up
    on some seeds in small rooms).

    Raises:
        PlacementError: no seed works.
    """
    from ..sim import person as person
    from ..sim.geometry import RoomGeometry

    if person_positions < 1:
        return 0
    geom = RoomGeometry.from_xml(resolve_scene(scene))
    for s in range(tries):
        try:
            person.walk(geom, n=person_positions, duration_s=duration_s, seed=s)
            return s
        except RfmError:
            continue
    raise PlacementError(f"no clear walk of {person_positions} positions in {scene} for seeds 0..{tries - 1}")


#: what every job's content depends on; the other keys of an ExperimentConfig only choose jobs, so
#: a later run into the same folder may add seeds, rooms, tables, ... (done jobs are reused)
SHARED_KEYS = ("size", "source", "data", "train")


def check_experiment(out: Path, cfg: ExperimentConfig) -> None:
    """RunError unless ``out`` is new, or an experiment folder of the same size, source, data and
    train (:data:`SHARED_KEYS`); reads only."""

    f = out / "experiment.toml"
    if f.is_file():
        have = C.to_dict(C.load(ExperimentConfig, f, saved=True))
        want = C.to_dict(cfg)
        diff = config_diff({k: have.get(k) for k in SHARED_KEYS}, {k: want[k] for k in SHARED_KEYS})
        if diff:
            raise RunError(f"output folder {out} holds another experiment configuration: {'; '.join(diff)}. "
                           "Use another --out (nothing was changed)")
    elif out.is_dir() and (out / "jobs").exists():
        raise RunError(f"{out} holds jobs but no experiment.toml; not an experiment folder (nothing was changed)")


def _saved_job(record: dict) -> dict:
    """A stored ``job.json`` with its method configuration read as a saved file (options removed
    or renamed since it was written load as the code now names them, :mod:`rfmitsuba.core.config`),
    so an unfinished job of an older folder resumes; left as stored where it does not read."""
    job = record.get("job")
    if isinstance(job, dict) and isinstance(job.get("method"), str):
        record = {**record, "job": {**job, "method": current_name(job["method"])}}
    mc = record.get("method_config")
    if isinstance(mc, dict):
        try:
            record = {**record, "method_config": json.loads(json.dumps(config_dict(C.from_dict(MethodConfig, mc,
                                                                                            saved=True))))}
        except ConfigError:
            pass
    return record


def reproduce_job(job: Job, out: Path, cfg: ExperimentConfig, data_dir: Path, *, quiet: bool = True,
                  reevaluate: bool = False) -> dict:
    """Train and evaluate one job by :func:`rfmitsuba.experiments.methods.run_job` (skipped when done, or
    evaluated again with ``reevaluate``); returns its metrics.

    Raises:
        RunError: the job folder holds a job of another configuration (``job.json`` differs).
    """

    jd = job.folder(out)
    mcfg = method_config(cfg.train, scene_known=cfg.source == "sionna")
    if not (jd / "DONE").is_file():
        want = {"job": job.record(), "method_config": config_dict(mcfg)}
        jt = jd / "job.json"
        if jt.is_file():
            diff = config_diff(_saved_job(json.loads(jt.read_text())), json.loads(json.dumps(want)))
            if diff:
                raise RunError(f"job folder {jd} belongs to another configuration: {'; '.join(diff)} "
                               "(nothing was changed)")
        jd.mkdir(parents=True, exist_ok=True)
        write_json_with_numpy(jt, want)
    prior = job.prior_job()
    if prior is not None:
        reproduce_job(prior, out, cfg, data_dir, quiet=quiet)
    return run_job(job.method, dataset_path(job.dataset, cfg, data_dir), jd, mcfg=mcfg, seed=job.seed,
                   record={"job": job.record()}, noise_snr_db=job.snr_db, train_antennas=job.positions,
                   layout=job.layout, walk_frames=job.walk_frames, reevaluate=reevaluate, quiet=quiet, **prior_kwargs(job.method, prior and prior.folder(out)),
                   floors_cache=Path(out) / FLOORS_FOLDER,
                   eval_dataset=dataset_path(job.eval_dataset, cfg, data_dir) if job.eval_dataset else None)


def report_finished(out: str | Path, cfg: ExperimentConfig | None = None) -> tuple[Path, int, int]:
    """Write ``out/report.md`` from the jobs finished so far, without training or generating
    anything: tables show a job not yet done as "-". Safe beside a running ``reproduce`` into
    ``out`` (it reads only finished jobs' ``metrics.json``; that run rewrites the report at its
    end). ``cfg`` None: the folder's own selection (``out/experiment.toml``, as its latest run
    saved it), so a report is never rewritten from a selection that run did not make.

    Returns:
        (report path, jobs finished, jobs in the configuration).
    Raises:
        RunError: ``out`` holds another configuration (the differing key is named) or no
        experiment at all.
    """
    out = Path(out)
    if not (out / "experiment.toml").is_file():
        raise RunError(f"{out} holds no reproduction (no experiment.toml): nothing to report")
    if cfg is None:
        cfg = C.load(ExperimentConfig, out / "experiment.toml", saved=True)
    else:
        check_experiment(out, cfg)
    jobs = all_jobs(cfg)
    results = {}
    for j in jobs:
        jd = j.folder(out)
        if (jd / "DONE").is_file() and (jd / "metrics.json").is_file():
            results[f"{j.dataset.key}/{j.key}"] = {**current_keys(json.loads((jd / "metrics.json").read_text())),
                                                   "job": j.record()}
    path = write_report(out, cfg, results, wall_s=None, jobs_total=len(jobs))
    return path, len(results), len(jobs)


class Stopped(RunError):
    """Raised by :func:`reproduce` after ``stop_after`` jobs (a simulated kill, for tests)."""


#: bytes on disk per PAS a dataset still has to generate [B]: its float32 90 x 360 image, its
#: complex64 channel, and its share of the 45 x 180 training images' cache (rfmitsuba.data.pas_cache)
BYTES_PER_PAS = 90 * 360 * 4 + 16 * 8 + 45 * 180 * 4
#: room left beside the datasets for jobs, truth checks and reports [B]
DISK_MARGIN = 1 << 30


def states_written(path: Path) -> int:
    """States of a partial dataset already on disk (their chunks are kept when it resumes)."""
    return sum(1 for _ in Path(path).glob("chunks/*/chunk.json"))


def dataset_specs(cfg: ExperimentConfig) -> list[DatasetSpec]:
    """Every dataset the jobs of ``cfg`` train or evaluate on, once each, in job order."""
    jobs = all_jobs(cfg)
    return list(dict.fromkeys([j.dataset for j in jobs] + [j.eval_dataset for j in jobs if j.eval_dataset]))


def disk_needed(specs: list[DatasetSpec], cfg: ExperimentConfig, data_dir: Path) -> int:
    """Bytes the datasets of ``specs`` still need in ``data_dir`` (states already written count
    as done): :data:`BYTES_PER_PAS` per PAS still to generate."""
    need = 0
    for spec in specs:
        positions, walk = dataset_shape(spec, cfg)
        states = 1 + walk
        need += max(states - states_written(dataset_path(spec, cfg, data_dir)), 0) * positions * BYTES_PER_PAS
    return need


def check_disk(specs: list[DatasetSpec], cfg: ExperimentConfig, data_dir: Path) -> None:
    """Refuse to start when the datasets still to generate do not fit on ``data_dir``'s file
    system (with :data:`DISK_MARGIN` to spare), before anything is written.

    Raises:
        RunError: naming the folder, the bytes needed and the bytes free.
    """
    need = disk_needed(specs, cfg, data_dir)
    if need == 0:
        return
    probe = Path(data_dir).resolve()
    while not probe.exists():
        probe = probe.parent
    free = shutil.disk_usage(probe).free
    if free < need + DISK_MARGIN:
        raise RunError(f"{data_dir}: the datasets still to generate need about {need / 1e9:.1f} GB (and "
                       f"{DISK_MARGIN / 1e9:.1f} GB beside them), but its file system has {free / 1e9:.1f} GB free; "
                       "free some space, or give --data a folder on a larger disk (datasets already there are reused)")


def reproduce(out: str | Path, cfg: ExperimentConfig, *, data_dir: str | Path | None = None,
              stop_after: int | None = None, reevaluate: bool = False, quiet: bool = False,
              cluster: ClusterConfig | None = None) -> Path:
    """Generate what is missing, run every job not yet done, write the report.

    Args:
        out: output folder (created; resumes an interrupted run of the same configuration).
        cfg: the experiment.
        data_dir: where datasets live (default ``out/data``); existing complete ones are reused.
        stop_after: raise :class:`Stopped` after this many newly finished jobs (tests).
        reevaluate: evaluate finished jobs again (after the evaluation changed; no retraining).
        quiet: no progress bars.
        cluster: where datasets (one task each) and jobs run (:mod:`rfmitsuba.core.cluster`;
            default here, one after another: the datasets, then the jobs; on Dask each job
            waits for its datasets, and Ours for its Baseline job, and then takes the first
            free worker, so jobs start while another worker still generates a dataset).

    Returns:
        path of ``report.md``.

    Raises:
        RunError: ``out`` holds another configuration (the differing key is named), another
        process is running a reproduction into it (:mod:`rfmitsuba.core.folder_lock`), or the
        datasets still to generate do not fit on the disk (:func:`check_disk`);
        JobsFailed (a RunError): on a cluster, datasets or jobs failed (each named; the
        others are done and kept).
    """

    out = Path(out)
    cluster = cluster or ClusterConfig()
    check_experiment(out, cfg)
    check_disk(dataset_specs(cfg), cfg, Path(data_dir) if data_dir else out / "data")   # before anything is written
    with folder_lock(out, what="reproduce"), sigterm_interrupts():   # a second reproduce into out stops at the lock
        return _reproduce(out, cfg, data_dir=data_dir, stop_after=stop_after, reevaluate=reevaluate, quiet=quiet,
                          cluster=cluster)


def _reproduce(out: Path, cfg: ExperimentConfig, *, data_dir, stop_after, reevaluate: bool, quiet: bool,
               cluster: ClusterConfig) -> Path:
    """:func:`reproduce` once its folder is checked and locked."""
    method_config(cfg.train, scene_known=cfg.source == "sionna")   # a bad override stops here, before any write
    C.save(cfg, out / "experiment.toml")        # the latest selection of jobs (the shared keys are checked)
    data_dir = Path(data_dir) if data_dir else out / "data"
    # workers elsewhere resolve relative paths against their own folder
    out_arg, data_arg = (out, data_dir) if cluster.serial else (out.resolve(), data_dir.resolve())
    jobs = all_jobs(cfg)
    specs = dataset_specs(cfg)
    truths = [Task(f"truth/{r}_{k}", ensure_truth, (r, k, cfg, out_arg), {"quiet": True})
              for r, k in truth_checks(cfg)]
    data_tasks = [Task(f"data/{s.key}", ensure_dataset, (s, cfg, data_arg), {"quiet": True}) for s in specs]
    names = [f"{j.dataset.key}/{j.key}" for j in jobs]
    # one graph: a job waits for its datasets (and Ours for its Baseline), not for every dataset,
    # so a worker starts jobs while the other still generates a long dataset; datasets and truth
    # checks come first in the list, which on Dask is also their priority among tasks ready to run
    tasks = [Task(n, reproduce_job, (j, out_arg, cfg, data_arg), {"quiet": True, "reevaluate": reevaluate},
                  after=(f"data/{j.dataset.key}",) + ((f"data/{j.eval_dataset.key}",) if j.eval_dataset else ())
                  + ((f"{j.dataset.key}/{j.prior_job().key}",) if j.prior_job() else ()))
             for n, j in zip(names, jobs)]
    new = {n for n, j in zip(names, jobs) if not (j.folder(out) / "DONE").is_file()}
    done_new = 0

    with _RunRecord(out, tables=list(cfg.tables)) as record:
        def count(name: str, _metrics: dict) -> None:
            nonlocal done_new
            if name in new:
                done_new += 1
                record.update(jobs_run=done_new)
                if stop_after is not None and done_new >= stop_after:
                    raise Stopped(f"stopped after {done_new} jobs (stop_after); run again to resume")

        try:
            done = run_tasks(data_tasks + truths + tasks, cluster=cluster,
                             desc="datasets" + (", truth checks" if truths else "") + " and jobs", unit="task",
                             quiet=quiet, on_result=count)
        except BaseException as e:   # an error, Stopped, Ctrl-C or SIGTERM: the time spent still counts
            record.end(jobs_run=done_new, stopped=type(e).__name__)
            raise
        results = {n: done[n] for n in names}
        wall = record.end(jobs_run=len(new))
    write_json_with_numpy(out / "results.json", results)

    return write_report(out, cfg, results, wall_s=wall)


#: marks a run's row in runs.jsonl until the run ends: a run killed without unwinding (SIGKILL,
#: a lost machine, the end of a machine's lease) keeps it, with its time up to its row's last rewrite
NO_END = "no end recorded (running, or killed)"

#: how often a running reproduction rewrites its row of runs.jsonl [s]
HEARTBEAT_S = 60.0


def record_run(out: Path, *, wall_s: float, jobs_run: int, tables: list[str], stopped: str | None = None,
               run_id: str | None = None) -> None:
    """Write a run's row in ``out/runs.jsonl`` (rewritten atomically): when it ended, its wall time
    [s], the jobs it finished (those not done before it), the tables it was asked for and, for a
    run that stopped early, why (the exception's name: ``KeyboardInterrupt``, ``Terminated`` for
    SIGTERM, ``Stopped``, ``JobsFailed``, ...; :data:`NO_END` while it runs), so a reproduction
    resumed over several sessions reports the time of all its runs. A row with the same
    ``run_id`` is replaced; without one, or with a new one, the row is appended."""
    f = Path(out) / RUNS_FILE
    lines = f.read_text().splitlines() if f.is_file() else []
    row = {"ended_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()), "wall_s": round(wall_s, 1),
           "jobs_run": int(jobs_run), "tables": tables}
    if stopped:
        row["stopped"] = stopped
    if run_id is not None:
        row["run"] = run_id
        lines = [line for line in lines if not line.strip() or json.loads(line).get("run") != run_id]
    lines.append(json.dumps(row))
    write_text(f, "\n".join(lines) + "\n")


class _RunRecord:
    """This run's row of ``runs.jsonl``, kept current while the run lasts: written when it starts,
    rewritten as each job finishes and every :data:`HEARTBEAT_S` seconds by a daemon thread, each
    time marked :data:`NO_END`; :meth:`end` writes its last form. A run killed where Python cannot
    unwind keeps its time up to the last rewrite."""

    def __init__(self, out: Path, *, tables: list[str]):
        self.out, self.tables = Path(out), tables
        self.run_id = f"{time.strftime('%Y%m%dT%H%M%S', time.gmtime())}-{os.getpid()}"
        self.t_start = time.perf_counter()
        self.jobs_run = 0
        self._lock = threading.Lock()             # the heartbeat and the main thread write the same file
        self._ended = threading.Event()
        self._beat = threading.Thread(target=self._heartbeat, name="runs.jsonl heartbeat", daemon=True)

    def __enter__(self) -> "_RunRecord":
        self._write(NO_END)
        self._beat.start()
        return self

    def __exit__(self, *exc) -> None:
        self._ended.set()
        self._beat.join()

    def update(self, *, jobs_run: int) -> None:
        """A job finished: ``jobs_run`` jobs are done by this run so far."""
        self.jobs_run = jobs_run
        self._write(NO_END)

    def end(self, *, jobs_run: int, stopped: str | None = None) -> float:
        """The run's last row: ``stopped`` names why it stopped early, None if it reached its end;
        returns its wall time [s]."""
        self._ended.set()
        self.jobs_run = jobs_run
        return self._write(stopped)

    def _heartbeat(self) -> None:
        while not self._ended.wait(HEARTBEAT_S):
            self._write(NO_END)

    def _write(self, stopped: str | None) -> float:
        with self._lock:
            if stopped == NO_END and self._ended.is_set():
                return time.perf_counter() - self.t_start   # the last row is written or being written
            wall = time.perf_counter() - self.t_start
            record_run(self.out, wall_s=wall, jobs_run=self.jobs_run, tables=self.tables, stopped=stopped,
                       run_id=self.run_id)
            return wall
