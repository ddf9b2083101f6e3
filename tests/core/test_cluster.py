"""rfmitsuba.core.cluster: jobs on Dask distributed give the serial results; failures are named.

One LocalCluster (2 worker processes, 1 thread each) serves these tests, reached as by
``--scheduler``; tests/experiments/test_compare.py runs a comparison by ``--workers 2``.
"""
from __future__ import annotations

import json
import math
import operator

import numpy as np
import pytest

from rfmitsuba.core.cluster import ClusterConfig, JobsFailed, Task, run_tasks
from rfmitsuba.core.errors import ConfigError

@pytest.fixture(scope="module")
def scheduler():
    """The address of a LocalCluster of 2 single-thread worker processes (module-wide)."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                      memory_limit=0) as lc:
        yield ClusterConfig(scheduler=lc.scheduler_address)


def test_config_errors():
    with pytest.raises(ConfigError, match="not both"):
        ClusterConfig(scheduler="tcp://127.0.0.1:8786", workers=2)
    with pytest.raises(ConfigError, match=">= 0"):
        ClusterConfig(workers=-1)
    with pytest.raises(ConfigError, match="not earlier tasks"):
        run_tasks([Task("a", math.sqrt, (4.0,), after=("b",)), Task("b", math.sqrt, (9.0,))])
    assert ClusterConfig().serial and not ClusterConfig(workers=1).serial


def test_serial_runs_in_order_and_names_the_failing_job():
    seen = []
    out = run_tasks([Task("a", math.sqrt, (4.0,)), Task("b", math.sqrt, (9.0,))], quiet=True,
                    on_result=lambda n, r: seen.append((n, r)))
    assert out == {"a": 2.0, "b": 3.0} and seen == [("a", 2.0), ("b", 3.0)]
    with pytest.raises(ZeroDivisionError) as e:  # the error itself, as before, with the job named
        run_tasks([Task("ok", math.sqrt, (4.0,)), Task("seed0/bad", operator.truediv, (1, 0))], quiet=True)
    assert "(in job seed0/bad)" in e.value.__notes__


def test_cluster_names_failed_jobs_and_keeps_the_others(scheduler, tmp_path):
    """A failing job is named, one that needed it is reported as not run, the others finish."""
    from rfmitsuba.core.atomic import write_json

    tasks = [Task("good", write_json, (tmp_path / "good.json", {"x": 1})),
             Task("seed1/bad", operator.truediv, (1, 0)),
             Task("seed1/ours", write_json, (tmp_path / "ours.json", {"x": 2}), after=("seed1/bad",)),
             Task("also_good", write_json, (tmp_path / "also.json", {"x": 3}), after=("good",))]
    with pytest.raises(JobsFailed) as e:
        run_tasks(tasks, cluster=scheduler, quiet=True)
    msg = str(e.value)
    assert "2 of 4 jobs failed" in msg
    assert "seed1/bad: ZeroDivisionError" in msg and "seed1/ours: not run, needs seed1/bad" in msg
    assert not [ln for ln in msg.splitlines() if ln.strip().startswith(("good", "also_good"))]
    assert set(e.value.failed) == {"seed1/bad"} and isinstance(e.value.__cause__, ZeroDivisionError)
    assert json.loads((tmp_path / "good.json").read_text()) == {"x": 1}
    assert json.loads((tmp_path / "also.json").read_text()) == {"x": 3}
    assert not (tmp_path / "ours.json").exists()
    # results come back in the order of the tasks, whatever order they finish in
    out = run_tasks([Task(f"t{i}", math.sqrt, (float(i * i),)) for i in range(5)], cluster=scheduler, quiet=True)
    assert list(out.items()) == [(f"t{i}", float(i)) for i in range(5)]


def test_generate_on_cluster_is_bit_identical(quick_dataset, scheduler, tmp_path):
    """States simulated on two workers (runs of consecutive states) give the serial chunks."""
    from rfmitsuba.sim import generate as gen

    ds = gen.generate(tmp_path / "ds", gen.quick_config("bedroom", task="rx", seed=0), quiet=True, cluster=scheduler)
    assert ds.num_states == quick_dataset.num_states
    for s in range(ds.num_states):
        for f in ("pas.npy", "channel.npy"):
            a = np.load(ds.path / "chunks" / f"{s:05d}" / f)
            b = np.load(quick_dataset.path / "chunks" / f"{s:05d}" / f)
            assert a.tobytes() == b.tobytes(), (s, f)
    timing = json.loads((ds.path / "timing.json").read_text())[-1]
    assert timing["states"] == ds.num_states and timing["workers"] == 2


def test_local_cluster_runs_tasks_in_priority_order():
    """``--workers N`` starts its LocalCluster without Dask's queue of root tasks: the tasks
    without dependencies listed first (datasets) all start before the jobs that wait for one of
    them, on both workers. With Dask's default queue (worker-saturation 1.1) 16 of these 24 jobs
    started before the last dataset, which the queue held back while jobs were ready."""
    import time

    from distributed import get_task_stream

    from rfmitsuba.core.cluster import session

    data = [Task(f"data/{i}", time.sleep, (0.4,)) for i in range(6)]
    jobs = [Task(f"job/{d}/{k}", time.sleep, (0.1,), after=(f"data/{d}",)) for d in range(6) for k in range(4)]
    with session(ClusterConfig(workers=2)) as s:
        assert math.isinf(s.client.run_on_scheduler(lambda dask_scheduler: dask_scheduler.WORKER_SATURATION))
        with get_task_stream(s.client) as stream:
            s.run(data + jobs, quiet=True)
    start = {r["key"].split("-", 2)[2]: min(ss["start"] for ss in r["startstops"] if ss["action"] == "compute")
             for r in stream.data}
    workers = {r["worker"] for r in stream.data if r["key"].split("-", 2)[2].startswith("data/")}
    assert len(start) == 30 and len(workers) == 2
    last_data = max(start[t.name] for t in data)
    assert sum(start[t.name] < last_data for t in jobs) <= 2
