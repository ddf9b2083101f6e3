"""Where a list of jobs runs: in this process one after another (the default), or on Dask distributed.

``compare``, ``reproduce`` and ``generate`` describe their work as :class:`Task` objects (a
name, a function of plain data, the names of the tasks it needs first) and hand them to
:func:`run_tasks` with a :class:`ClusterConfig`:

* neither ``scheduler`` nor ``workers``: every task runs here, in list order, as it always did;
* ``workers=N``: a Dask ``LocalCluster`` of N worker processes with one thread each is
  started for the call and shut down after it;
* ``scheduler="tcp://host:8786"``: the tasks go to a running Dask scheduler (start it with
  ``DASK_DISTRIBUTED__SCHEDULER__WORKER_SATURATION=inf dask scheduler``, so that tasks run in
  the order of their priority (:data:`WORKER_SATURATION`), workers with ``dask worker ADDRESS
  --nthreads 1 --nworkers K``). The workers must import rfmitsuba and see the same file
  system: tasks get absolute paths.

Every task writes its own folder and skips work a finished earlier run did, so a run on a
cluster resumes exactly as a serial one. A task runs in a worker with Dr.Jit on as many
threads as the worker has (one for the ``LocalCluster``, and then its result is bit-identical
to a serial run on one Dr.Jit thread: seeds come from the task, never from the worker), in
the Mitsuba variant of the submitting process; tasks of one worker process run one at a time.

A task that fails does not stop the others: when all have ended, :class:`JobsFailed` names
every failed task (with its error) and the finished ones keep their results on disk.

This module is infrastructure like :mod:`rfmitsuba.core.progress`: it knows nothing of
training or datasets, and imports ``distributed`` only when a cluster is asked for.
"""
from __future__ import annotations

import contextlib
import threading
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from dataclasses import field as dc_field
from typing import Any

from .errors import ConfigError, RunError
from .progress import bar


@dataclass(frozen=True)
class ClusterConfig:
    """Where :func:`run_tasks` runs its tasks.

    scheduler: address of a running Dask scheduler (e.g. ``"tcp://10.0.0.5:8786"``); workers:
    number of single-thread worker processes of a ``LocalCluster`` to start (0 = none). Give
    at most one; with neither, tasks run in this process one after another.
    """

    scheduler: str | None = None
    workers: int = 0

    def __post_init__(self) -> None:
        if self.workers < 0:
            raise ConfigError(f"--workers must be >= 0, got {self.workers}")
        if self.scheduler and self.workers:
            raise ConfigError("give either --scheduler ADDRESS or --workers N, not both")

    @property
    def serial(self) -> bool:
        """True when tasks run in this process (no scheduler, no workers)."""
        return not self.scheduler and not self.workers


@dataclass(frozen=True)
class Task:
    """One job: ``fn(*args, **kwargs)`` under a unique ``name``, run after the tasks named in ``after``.

    ``fn`` must be importable by name (a module-level function) and ``args``/``kwargs`` plain,
    picklable data (paths, numbers, dataclass configurations), never Dr.Jit arrays: on a
    cluster they travel to another process.
    """

    name: str
    fn: Callable[..., Any]
    args: tuple = ()
    kwargs: dict = dc_field(default_factory=dict)
    after: tuple[str, ...] = ()


class JobsFailed(RunError):
    """Some tasks of :func:`run_tasks` on a cluster failed; ``failed`` maps their names to their errors."""

    def __init__(self, message: str, failed: dict[str, BaseException] | None = None):
        super().__init__(message)
        self.failed = dict(failed or {})

    def __reduce__(self):
        return (type(self), (str(self), self.failed))


def add_cli_options(parser) -> None:
    """Add ``--scheduler ADDRESS`` and ``--workers N`` to an argparse (sub)parser."""
    g = parser.add_argument_group("Dask distributed (default: every job here, one after another)")
    g.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="submit the jobs to a running Dask scheduler, e.g. tcp://host:8786 (its workers need "
                        "rfmitsuba and the same file system; start them with --nthreads 1)")
    g.add_argument("--workers", type=int, default=0, metavar="N",
                   help="start a Dask LocalCluster of N worker processes, one thread each, for this run")


def from_cli(args) -> ClusterConfig:
    """The :class:`ClusterConfig` of parsed ``--scheduler`` / ``--workers`` options."""
    return ClusterConfig(scheduler=getattr(args, "scheduler", None), workers=getattr(args, "workers", 0) or 0)


#: ``distributed.scheduler.worker-saturation`` of the ``LocalCluster`` that ``--workers N`` starts:
#: "inf", no queue. Dask's default (1.1) keeps tasks without dependencies (datasets, truth
#: checks) in a queue on the scheduler until a worker runs fewer tasks than it has threads, which
#: never happens while jobs are ready: a full reproduction had run 61 jobs of its first four
#: datasets in 66 min, with 43 more on its workers, and not started a fifth, and risked ending on one worker generating the
#: large room's dataset (1506 s) while the other idled. Without the queue the tasks' priorities
#: (datasets, then truth checks, then jobs, :func:`run_tasks`) decide, on either worker
#: (tests/core/test_cluster.py). A scheduler of your own (``--scheduler``) keeps its setting:
#: start it with ``DASK_DISTRIBUTED__SCHEDULER__WORKER_SATURATION=inf``.
WORKER_SATURATION = "inf"


class Session:
    """An open Dask client (and the ``LocalCluster`` it started, if any); see :func:`session`."""

    def __init__(self, client, cluster=None):
        self.client = client
        self.cluster = cluster

    @property
    def num_workers(self) -> int:
        """Workers connected to the scheduler now (at least 1)."""
        return max(1, len(self.client.scheduler_info(n_workers=-1).get("workers", {})))

    def run(self, tasks: Sequence[Task], *, desc: str = "jobs", unit: str = "job", quiet: bool = False,
            on_result: Callable[[str, Any], None] | None = None) -> dict[str, Any]:
        """Submit ``tasks`` (each after those it names in ``after``), wait for all; see :func:`run_tasks`."""
        from distributed import as_completed

        from . import backend

        _check_tasks(tasks)
        variant = backend.variant()  # the workers use the variant of the submitting process
        run_id = uuid.uuid4().hex[:8]
        futures: dict[str, Any] = {}
        for i, t in enumerate(tasks):
            deps = [futures[d] for d in t.after]
            # priority in list order: the caller lists related jobs (one dataset's) together, and
            # free workers should take them together (Dask does not promise an order otherwise)
            futures[t.name] = self.client.submit(_run_in_worker, variant, t.fn, t.args, t.kwargs, *deps,
                                                 key=f"rfm-{run_id}-{t.name}", pure=False,
                                                 priority=len(tasks) - i)
        name_of = {f.key: n for n, f in futures.items()}
        after = {t.name: t.after for t in tasks}
        results: dict[str, Any] = {}
        failed: dict[str, BaseException] = {}
        try:
            with bar(len(tasks), desc=desc, unit=unit, quiet=quiet) as pb:
                for fut in as_completed(list(futures.values())):
                    name = name_of[fut.key]
                    if fut.status == "finished":
                        results[name] = fut.result()
                        if on_result is not None:
                            on_result(name, results[name])
                    else:
                        failed[name] = fut.exception()
                    pb.update(1)
        finally:
            self.client.cancel([f for f in futures.values() if not f.done()])
        if failed:
            raise _failure(tasks, failed, after)
        return {t.name: results[t.name] for t in tasks}

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


@contextlib.contextmanager
def session(cfg: ClusterConfig) -> Iterator[Session]:
    """A Dask client for ``cfg`` (not serial): connected to ``cfg.scheduler``, or to a new
    ``LocalCluster`` of ``cfg.workers`` single-thread processes, which is shut down on exit.

    Raises:
        ConfigError: ``cfg`` is serial, or ``distributed`` is not installed.
        RunError: no scheduler answers at ``cfg.scheduler``.
    """
    if cfg.serial:
        raise ConfigError("cluster.session needs --scheduler or --workers")
    try:
        from distributed import Client, LocalCluster
    except ImportError as e:  # pragma: no cover - a dependency of the package
        raise ConfigError(f"--scheduler/--workers need Dask distributed: pip install distributed ({e})") from None
    cluster = None
    if cfg.scheduler:
        try:
            client = Client(cfg.scheduler, timeout="30s")
        except OSError as e:
            raise RunError(f"no Dask scheduler answers at {cfg.scheduler}: {e}") from None
    else:
        import dask

        # no memory limit: a job is one long process that manages its own memory, and Dask's
        # pausing / killing at a fraction of RAM / N would stall or restart training jobs.
        # No queue of root tasks (WORKER_SATURATION): every task goes to a worker at once, and
        # each worker runs its ready tasks in the order of their priority
        with dask.config.set({"distributed.scheduler.worker-saturation": WORKER_SATURATION}):
            cluster = LocalCluster(n_workers=cfg.workers, threads_per_worker=1, processes=True, memory_limit=0,
                                   dashboard_address=None)
        client = Client(cluster)
    s = Session(client, cluster)
    try:
        yield s
    finally:
        s.close()


def run_tasks(tasks: Sequence[Task], *, cluster: ClusterConfig | None = None, desc: str = "jobs",
              unit: str = "job", quiet: bool = False,
              on_result: Callable[[str, Any], None] | None = None) -> dict[str, Any]:
    """Run ``tasks`` where ``cluster`` says and return {task name: result} in the order of ``tasks``.

    Args:
        tasks: the jobs; names unique, each ``after`` naming earlier tasks only.
        cluster: where (None or serial: here, one after another in list order, exactly as a
            loop would; an error stops the run and propagates unchanged, with the task's
            name added as a note).
        desc, unit, quiet: the tqdm progress bar (one step per finished task).
        on_result: called here as ``on_result(name, result)`` as each task finishes (in
            completion order on a cluster); an exception it raises stops the run (tasks not
            started are cancelled) and propagates.

    Raises:
        JobsFailed: on a cluster, after every task has ended, naming each that failed (and
            the tasks not run because one they needed failed); the others keep their results.
    """
    cluster = cluster or ClusterConfig()
    if cluster.serial:
        _check_tasks(tasks)
        out: dict[str, Any] = {}
        with bar(len(tasks), desc=desc, unit=unit, quiet=quiet) as pb:
            for t in tasks:
                try:
                    out[t.name] = t.fn(*t.args, **t.kwargs)
                except Exception as e:
                    e.add_note(f"(in job {t.name})")
                    raise
                if on_result is not None:
                    on_result(t.name, out[t.name])
                pb.update(1)
        return out
    with session(cluster) as s:
        return s.run(tasks, desc=desc, unit=unit, quiet=quiet, on_result=on_result)


def _check_tasks(tasks: Sequence[Task]) -> None:
    seen: set[str] = set()
    for t in tasks:
        if t.name in seen:
            raise ConfigError(f"two tasks are named {t.name!r}")
        missing = [d for d in t.after if d not in seen]
        if missing:
            raise ConfigError(f"task {t.name!r} runs after {missing}, which are not earlier tasks")
        seen.add(t.name)


def _failure(tasks: Sequence[Task], failed: dict[str, BaseException], after: dict[str, tuple[str, ...]]) -> JobsFailed:
    """The error of a cluster run: the tasks that failed themselves, then those that needed them."""

    def root(name: str) -> str | None:  # a failed task this one needed (directly or not)
        for d in after[name]:
            if d in failed:
                return root(d) or d
        return None

    own = [n for n in failed if root(n) is None]
    lines = [f"{n}: {type(failed[n]).__name__}: {failed[n]}" for n in own]
    lines += [f"{n}: not run, needs {root(n)}" for n in failed if root(n) is not None]
    msg = (f"{len(failed)} of {len(tasks)} jobs failed; the {len(tasks) - len(failed)} others finished and keep "
           "their results (run the same command again to resume):\n  " + "\n  ".join(lines))
    err = JobsFailed(msg, {n: failed[n] for n in own})
    err.__cause__ = failed[own[0]] if own else None
    return err


_LOCK = threading.Lock()


def _run_in_worker(variant: str, fn: Callable[..., Any], args: tuple, kwargs: dict, *_done: Any) -> Any:
    """Run one task in a Dask worker: the submitter's Mitsuba variant, Dr.Jit on the worker's
    threads, one task of this process at a time (``_done``: results of the tasks it waited for)."""
    with _LOCK:
        import drjit as dr

        from . import backend
        from .memory import keep_freed_memory

        keep_freed_memory()

        if backend._variant != variant:
            backend.set_variant(variant)
        try:
            from distributed import get_worker

            threads = get_worker().state.nthreads
        except (ImportError, ValueError, AttributeError):
            threads = 1
        dr.set_thread_count(max(1, int(threads)))
        return fn(*args, **kwargs)
