"""rfmitsuba.experiments.plan: jobs still to run per table, timed by finished jobs; writes nothing."""
from __future__ import annotations

import statistics

import pytest

from rfmitsuba.core import config as C
from rfmitsuba.core.errors import RunError
from rfmitsuba.experiments import plan as P
from rfmitsuba.experiments.job import Job
from rfmitsuba.experiments.paper_tables import all_jobs
from rfmitsuba.experiments.sizes import DatasetSpec


def test_job_kind_drops_only_the_seed():
    ds = DatasetSpec("bedroom", "rx")
    assert P.job_kind(Job(ds, "baseline", 12)) == "baseline"
    assert P.job_kind(Job(ds, "ours", 0, snr_db=10.0)) == "ours_snr10"
    assert P.job_kind(Job(ds, "baseline", 3, positions=1800, eval_dataset=DatasetSpec("bedroom", "rx"))) \
        == "baseline_n1800_on_bedroom_rx_tissue"


def test_a_finished_run_has_nothing_left(tiny_reproduction):
    out, cfg, _, _ = tiny_reproduction
    p = P.plan(out, cfg)
    assert p.total.jobs == p.total.done == len(all_jobs(cfg)) and p.total.to_run == 0 and p.total.estimate_s == 0
    assert all(d.complete for d in p.datasets) and p.measured_jobs == len(all_jobs(cfg))
    text = P.format_plan(p)
    assert f"| **all** | {p.total.jobs} | {p.total.jobs} | 0 | 0.00 | 0 |" in text


def test_new_seeds_are_timed_by_the_finished_jobs_of_their_kind(tiny_reproduction, tmp_path):
    out, cfg, _, _ = tiny_reproduction
    more = C.override(cfg, ["seeds=[0, 1, 2, 5]"])
    p = P.plan(out, more)
    new = [j for j in all_jobs(more) if j.seed == 5]
    times = P.measured_times([out])
    want = sum(statistics.median(times[P.job_kind(j)]) for j in new)
    assert p.total.to_run == len(new) and p.total.unestimated == 0
    assert p.total.estimate_s == pytest.approx(want)
    # a new folder is timed by a reference folder and not created
    fresh = tmp_path / "new"
    q = P.plan(fresh, cfg, data_dir=out / "data", reference=[out])
    assert q.total.to_run == len(all_jobs(cfg)) and q.total.unestimated == 0 and q.total.estimate_s > 0
    assert not fresh.exists()
    # without any finished job nothing is estimated, and missing datasets are named
    r = P.plan(fresh, cfg)
    assert r.total.unestimated == r.total.to_run and r.total.estimate_s == 0
    assert not any(d.complete for d in r.datasets) and all(d.estimate_s is None for d in r.datasets)
    assert "| not estimated |" in P.format_plan(r) and "plus what is not estimated" in P.format_plan(r)
    assert not fresh.exists()


def test_makespan_is_list_scheduling_with_dependencies():
    # one worker: the sum; two: each task to the worker free first
    assert P.makespan([3.0, 1.0, 2.0], workers=1) == 6.0
    assert P.makespan([3.0, 1.0, 2.0], workers=2) == 3.0            # 3 | 1 then 2
    assert P.makespan([3.0, 1.0, 2.0], workers=2, start=10.0) == 13.0
    # task 2 builds on task 0: it waits for it although worker 2 is free at 1
    assert P.makespan([3.0, 1.0, 2.0], workers=2, after=[None, None, 0]) == 5.0
    assert P.makespan([], workers=4, start=7.0) == 7.0
    # a free worker takes the first task that is ready: the two jobs on the short dataset 1 run
    # while dataset 0 is generated (strictly in list order they would wait behind job 2: 14)
    assert P.makespan([10.0, 1.0, 2.0, 2.0, 2.0], workers=2, after=[None, None, 0, 1, (1,)]) == 12.0
    assert P.makespan([10.0, 1.0, 2.0], workers=2, after=[None, None, (0, 1)]) == 12.0
    with pytest.raises(ValueError, match="workers"):
        P.makespan([1.0], workers=0)


def test_plan_on_workers_is_shorter_than_one_at_a_time(tiny_reproduction, tmp_path, capsys):
    from rfmitsuba.cli import main

    out, cfg, _, _ = tiny_reproduction
    fresh = tmp_path / "new"
    one = P.plan(fresh, cfg, data_dir=out / "data", reference=[out])
    two = P.plan(fresh, cfg, data_dir=out / "data", reference=[out], workers=2)
    assert one.makespan_s == pytest.approx(one.total.estimate_s)   # the datasets are complete
    assert one.total.estimate_s / 2 <= two.makespan_s < one.makespan_s
    assert main(["reproduce", "--size", "tiny", "--out", str(fresh), "--data", str(out / "data"), "--plan",
                 "--plan-from", str(out), "--workers", "2"]) == 0
    assert "On 2 single-thread workers" in capsys.readouterr().out and not fresh.exists()


def test_another_configuration_is_refused_as_by_reproduce(tiny_reproduction):
    out, cfg, _, _ = tiny_reproduction
    with pytest.raises(RunError, match="data.positions"):
        P.plan(out, C.override(cfg, ["data.positions=26"]))


def test_cli_plan_prints_and_writes_nothing(tiny_reproduction, tmp_path, capsys):
    from rfmitsuba.cli import main

    out, _, _, _ = tiny_reproduction
    fresh = tmp_path / "planned"
    assert main(["reproduce", "--size", "tiny", "--out", str(fresh), "--data", str(out / "data"), "--plan",
                 "--plan-from", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| **all** |" in text and "estimated wall time (h)" in text and not fresh.exists()
    assert main(["reproduce", "--size", "tiny", "--out", str(fresh), "--plan-from", str(out)]) != 0
    assert "--plan-from goes with --plan" in capsys.readouterr().err and not fresh.exists()


def test_cli_plan_without_a_selection_plans_the_folders_own(tiny_reproduction, capsys):
    """A bare ``--plan`` on an existing folder plans its experiment.toml's jobs (here the tiny
    size's, all finished), not the default size's tables (which differ from the folder's and were
    refused as another configuration)."""
    from rfmitsuba.cli import main

    out, cfg, _, _ = tiny_reproduction
    n = len(all_jobs(cfg))
    assert main(["reproduce", "--out", str(out), "--plan"]) == 0
    captured = capsys.readouterr()
    assert f"| **all** | {n} | {n} | 0 | 0.00 | 0 |" in captured.out
    assert "its own selection" in captured.err
    # a selection on the command line is still checked against the folder
    assert main(["reproduce", "--out", str(out), "--size", "full", "--plan"]) != 0
    assert "holds another experiment configuration" in capsys.readouterr().err


def test_datasets_to_generate_are_timed_by_those_generated(tmp_path):
    """A missing dataset is estimated by the seconds per PAS of generated datasets (same scene and
    task first, else any), counting only the states a partial dataset has not written yet."""
    import json

    from rfmitsuba.experiments.reproduce import dataset_path
    from rfmitsuba.experiments.sizes import size_config

    cfg = size_config("tiny")
    data = tmp_path / "data"

    def generated(name, scene, task, positions, sessions):
        d = data / name
        d.mkdir(parents=True)
        (d / "meta.json").write_text(json.dumps({"num_antenna_positions": positions, "task": task,
                                                 "generate": {"scene": scene}}))
        (d / "timing.json").write_text(json.dumps(sessions))

    specs = list(dict.fromkeys(j.dataset for j in all_jobs(cfg)))
    spec = specs[0]
    generated("same", spec.scene, spec.task, 100, [{"states": 1, "total_s": 5.0},     # 0.1 s per PAS,
                                                   {"states": 1, "total_s": 15.0}])   # two sessions
    generated("other", "elsewhere", "tx", 10, [{"states": 1, "total_s": 100.0}])      # 10 s per PAS
    generated("broken", spec.scene, spec.task, 10, [{"oops": 1}])            # not a measurement
    rates = P.generation_rates([data])
    assert rates[f"{spec.scene}/{spec.task}"] == [pytest.approx(0.1)] and len(rates["any"]) == 2
    # one state of this spec's dataset is already on disk: it is not counted again
    path = dataset_path(spec, cfg, data)
    (path / "chunks" / "00000").mkdir(parents=True)
    (path / "chunks" / "00000" / "chunk.json").write_text("{}")
    p = P.plan(tmp_path / "out", cfg, data_dir=data)
    d = next(d for d in p.datasets if d.key == spec.key)
    states = 1 if spec.static_positions else 1 + cfg.data.person_positions
    positions = spec.static_positions or cfg.data.positions
    assert not d.complete and d.pas_left == (states - 1) * positions
    assert d.estimate_s == pytest.approx(0.1 * d.pas_left) and d.timed_by == f"{spec.scene}/{spec.task}"
    text = P.format_plan(p)
    assert f"| {spec.key} | {d.pas_left} | " in text and "Estimated total:" in text
    assert not (tmp_path / "out").exists()


def test_truth_checks_left_are_listed_and_not_estimated(tmp_path):
    """A Sionna run's truth checks (one per room x task of the main table) are counted as done once
    their summary is written; those left make the total 'plus what is not estimated'."""
    import json

    from rfmitsuba.experiments.sizes import size_config
    from rfmitsuba.experiments.truth import truth_folder

    cfg = size_config("quick")
    cfg.rooms, cfg.tasks = ["bedroom"], ["rx", "tx"]
    f = truth_folder(tmp_path / "out", "bedroom", "rx")
    f.mkdir(parents=True)
    (f / "summary.json").write_text(json.dumps({"stats": {}}))
    p = P.plan(tmp_path / "out", cfg)
    assert p.truth_checks == ["bedroom_rx", "bedroom_tx"] and p.truth_left == ["bedroom_tx"]
    text = P.format_plan(p)
    assert "Truth checks beside the main table: 2 needed, 1 done, 1 to run (not estimated: bedroom_tx)" in text
    assert "plus what is not estimated" in text
    assert P.plan(tmp_path / "other", size_config("tiny")).truth_checks == []   # synthetic data
