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
    assert all(ok for _, _, ok in p.datasets) and p.measured_jobs == len(all_jobs(cfg))
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
    assert not any(ok for _, _, ok in r.datasets) and "to generate (not estimated)" in P.format_plan(r)
    assert not fresh.exists()


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
