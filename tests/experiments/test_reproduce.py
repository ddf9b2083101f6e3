"""reproduce: tiny end to end, kill and resume, other configurations refused, config round trip."""
from __future__ import annotations

import json
import re

import pytest

from rfmitsuba.core.errors import RunError


def test_report_has_every_table(tiny_reproduction):
    out, cfg, report, _ = tiny_reproduction
    text = report.read_text()
    for heading in ("Main table", "Two-stage ablation", "Role of perturbation data", "Number of training positions",
                    "Measurement noise", "Static positions against one walk", "Speed against accuracy",
                    "Where methods break", "Paper claims", "Wall time per table"):
        assert heading in text, heading
    assert "0.927 / 0.967" in text  # the paper's Ours figure for scene 1, moving RX, beside ours
    assert " ± " in text and ("**holds**" in text or "**does not hold**" in text or "**unclear**" in text)
    # the Rx-count table: Baseline trained on the extra empty-room dataset, tested on the main one
    assert re.search(r"\| Baseline \| 30 \| 0\.\d+ ± 0\.\d+ \| 0\.\d+ ± ", text)
    assert "effect " in text and "over 3 seeds (per seed " in text
    assert re.search(r"\| \*\*all\*\* \| (\d+) \| \1 \| \d+\.\d \|", text)   # every job done and timed
    for png in (out / "speed_accuracy.png", out / "rx_count.png"):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "![Static positions against one walk](rx_count.png)" in text
    assert "time to within 0.005 (s)" in text
    assert re.search(r"\| \w+ \| Ours \(two-stage\) \| 3 \| 0\.\d+ ± ", text)  # a curve for every seed
    res = json.loads((out / "results.json").read_text())
    assert {r["job"]["seed"] for r in res.values()} == set(cfg.seeds)
    r = next(iter(res.values()))
    assert r["eval"]["dynamic"]["model"]["n"] > 0 and r["eval"]["static"]["model"]["n"] > 0
    assert "where the person matters" in text and "affected" in r["eval"]


def test_resume_skips_finished_jobs(tiny_reproduction):
    from rfmitsuba.experiments.reproduce import all_jobs

    out, cfg, _, before = tiny_reproduction
    assert len(before) == 4
    for p, t in before.items():
        assert p.stat().st_mtime_ns == t  # not recomputed
    assert len(list(out.glob("jobs/*/*/DONE"))) == len(all_jobs(cfg))
    # both runs are recorded: the stopped one with its 4 jobs and why it stopped, then the resumed
    # one that reached its end (later tests may add runs)
    first, second = (json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()[:2])
    assert first["jobs_run"] == 4 and first["stopped"] == "Stopped" and first["wall_s"] > 0
    assert second["jobs_run"] == len(all_jobs(cfg)) - 4 and second["wall_s"] > 0 and second["tables"] == cfg.tables
    assert "stopped" not in second


def test_other_configuration_is_refused(tiny_reproduction):
    """Another size, data or training configuration is refused by name and changes nothing; other
    seeds, rooms or tables only choose jobs and are accepted."""
    from rfmitsuba.core import config as C
    from rfmitsuba.experiments.reproduce import check_experiment, reproduce

    out, cfg, _, _ = tiny_reproduction
    before = (out / "experiment.toml").read_text()
    with pytest.raises(RunError, match=r"data.positions \(run has 25, requested 26\)"):
        reproduce(out, C.override(cfg, ["data.positions=26"]), quiet=True)
    with pytest.raises(RunError, match="train.stage2_iterations"):
        reproduce(out, C.override(cfg, ["train.stage2_iterations=31"]), quiet=True)
    assert (out / "experiment.toml").read_text() == before
    check_experiment(out, C.override(cfg, ["seeds=[0, 1, 7]", 'tables=["main"]']))


def test_job_folder_of_another_job_is_refused(tiny_reproduction, tmp_path):
    from rfmitsuba.experiments.reproduce import Job, reproduce_job
    from rfmitsuba.experiments.sizes import DatasetSpec

    out, cfg, _, _ = tiny_reproduction
    job = Job(DatasetSpec("bedroom", "rx"), "baseline", 0)
    jd = job.folder(tmp_path)
    jd.mkdir(parents=True)
    rec = json.loads((job.folder(out) / "job.json").read_text())
    rec["job"]["seed"] = 99
    (jd / "job.json").write_text(json.dumps(rec))
    with pytest.raises(RunError, match="job.seed"):
        reproduce_job(job, tmp_path, cfg, out / "data")


def test_config_round_trip_and_jobs():
    from rfmitsuba.core import config as C
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.experiments.reproduce import all_jobs
    from rfmitsuba.experiments.sizes import PAPER_SIZES, SIZES, ExperimentConfig, size_config

    for name in SIZES:
        cfg = size_config(name)
        assert C.from_toml(ExperimentConfig, C.to_toml(cfg)) == cfg
        jobs = all_jobs(cfg)
        keys = [f"{j.dataset.key}/{j.key}" for j in jobs]
        assert len(keys) == len(set(keys))
        for i, j in enumerate(jobs):
            if j.prior_job() is not None:  # what it builds on (Ours: its Baseline) runs first
                b = j.prior_job()
                assert keys.index(f"{b.dataset.key}/{b.key}") < i
        assert len(cfg.seeds) >= 3 or name not in PAPER_SIZES  # the paper's sizes claim over 3 seeds
    assert set(PAPER_SIZES) <= set(SIZES)
    with pytest.raises(ConfigError, match="unknown size"):
        size_config("huge")
    with pytest.raises(ConfigError, match="tables"):
        ExperimentConfig(tables=["everything"])


def test_reevaluate_rewrites_metrics_without_training(tiny_reproduction, tmp_path):
    """``reevaluate``: every finished job is evaluated again (a damaged figure comes back), its
    training runs are not touched."""
    import shutil

    from job_metrics import age_metrics

    from rfmitsuba.experiments.reproduce import reproduce

    src, cfg, _, _ = tiny_reproduction
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    mfile = sorted(out.glob("jobs/*/ours_s0/metrics.json"))[0]
    good = age_metrics(mfile)
    runs = {p: p.stat().st_mtime_ns for p in out.glob("jobs/*/*/*/final/*")}
    assert runs
    reproduce(out, cfg, reevaluate=True, quiet=True)
    new = json.loads(mfile.read_text())
    assert "affected" in new["eval"] and new["train"] == good["train"]
    assert new["eval"]["dynamic"]["model"]["mean"] == pytest.approx(good["eval"]["dynamic"]["model"]["mean"], abs=1e-3)
    assert all(p.stat().st_mtime_ns == t for p, t in runs.items())


def test_report_only_writes_the_finished_jobs(tiny_reproduction, tmp_path, capsys):
    """`reproduce --report-only` writes the report from the finished jobs alone: unfinished ones
    show as "-", nothing is trained, generated or marked done; without a size on the command line
    it reports the folder's own selection; a folder without a reproduction is named."""
    import shutil

    from rfmitsuba.cli import main
    from rfmitsuba.experiments.reproduce import all_jobs, report_finished

    src, cfg, _, _ = tiny_reproduction
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    (out / "report.md").unlink()
    pending = sorted(out.glob("jobs/*/*/DONE"))[:3]
    for marker in pending:
        marker.unlink()
    stamps = {p: p.stat().st_mtime_ns for p in out.glob("jobs/*/*/metrics.json")}
    total = len(all_jobs(cfg))
    path, done, jobs = report_finished(out, cfg)
    assert (done, jobs) == (total - 3, total)
    text = path.read_text()
    assert f"from the {total - 3} of {total} jobs finished so far" in text and "| - |" in text
    assert "Main table" in text and "Paper claims" in text
    assert {p: p.stat().st_mtime_ns for p in out.glob("jobs/*/*/metrics.json")} == stamps
    assert not any(m.exists() for m in pending)
    assert main(["reproduce", "--out", str(out), "--size", "tiny", "--report-only"]) == 0
    assert f"report of {total - 3} of {total} jobs finished" in capsys.readouterr().out
    # no selection on the command line: the folder's own (not the default size's tables)
    assert main(["reproduce", "--out", str(out), "--report-only"]) == 0
    assert f"report of {total - 3} of {total} jobs finished" in capsys.readouterr().out
    with pytest.raises(RunError, match="holds no reproduction"):
        report_finished(tmp_path / "empty", cfg)


def test_a_bare_rerun_resumes_the_folders_own_selection(tiny_reproduction, tmp_path, capsys):
    """``reproduce --out OUT`` with no size, config, tables or set resumes OUT's own experiment
    (a killed tiny run finishes as tiny), where it was refused as the full size before."""
    import json
    import shutil

    from rfmitsuba.cli import main
    from rfmitsuba.experiments.reproduce import all_jobs

    src, cfg, _, _ = tiny_reproduction
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    marker = sorted(out.glob("jobs/*/*/DONE"))[0]
    marker.unlink()
    kept = {p: p.stat().st_mtime_ns for p in out.glob("jobs/*/*/DONE")}
    assert main(["reproduce", "--out", str(out), "--data", str(src / "data"), "--quiet"]) == 0
    assert marker.is_file() and {p: p.stat().st_mtime_ns for p in kept} == kept
    assert "its own selection" in capsys.readouterr().err
    assert json.loads((marker.parent / "metrics.json").read_text())
    assert len(list(out.glob("jobs/*/*/DONE"))) == len(all_jobs(cfg))


def test_solver_config_scales_each_rooms_default_samples():
    """The full size traces a quarter of each room's default ray samples; an explicit count wins;
    scale 1 leaves the room's default to the generator."""
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.experiments.reproduce import solver_config
    from rfmitsuba.experiments.sizes import DataSize, size_config

    assert size_config("full").data.samples_scale == 0.25
    assert solver_config("bedroom", DataSize(samples_scale=0.25)).samples_per_src == 25_000
    assert solver_config("large_room", DataSize(samples_scale=0.25)).samples_per_src == 75_000  # 3e5 over 50 m^2
    assert solver_config("bedroom", DataSize(samples_per_src=12_345, samples_scale=0.25)).samples_per_src == 12_345
    assert solver_config("bedroom", DataSize()) is None
    for bad in (0.0, 1.5, -0.1):
        with pytest.raises(ConfigError, match="samples_scale"):
            DataSize(samples_scale=bad)


def test_truth_checks_run_beside_the_main_table_at_the_datasets_samples(monkeypatch, tmp_path):
    """Every room x task of the main table gets a truth check on Sionna data, at the datasets' ray
    samples, in its folder of the reproduction; synthetic data and truth_positions = 0 get none."""
    from rfmitsuba.experiments import truth
    from rfmitsuba.experiments.reproduce import ensure_truth, truth_checks
    from rfmitsuba.experiments.sizes import size_config

    full = size_config("full")
    assert truth_checks(full) == [(r, k) for r in ("bedroom", "living_room", "dining_room") for k in ("rx", "tx")]
    assert full.truth_positions == 48
    assert truth_checks(size_config("tiny")) == []                   # synthetic: no ray tracer to check
    full.tables = ["noise"]
    assert truth_checks(full) == []                                  # no main table to place it beside
    calls = []

    def fake(out, cfg, *, quiet):
        calls.append((out, cfg))
        return {"stats": {"ssim": {"mean": 0.9}}}

    monkeypatch.setattr(truth, "truth_uncertainty", fake)
    assert ensure_truth("bedroom", "tx", size_config("full"), tmp_path) == {"mean": 0.9}
    (out, tc), = calls
    assert out == tmp_path / "truth" / "bedroom_tx"
    assert (tc.scene, tc.task, tc.positions, tc.samples) == ("bedroom", "tx", 48, 25_000)


def test_truth_positions_are_bounded_by_the_exact_arrays_limit():
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.experiments.sizes import ExperimentConfig
    from rfmitsuba.sim.generate import EXACT_MAX_POSITIONS

    ExperimentConfig(truth_positions=EXACT_MAX_POSITIONS)
    for bad in (-1, EXACT_MAX_POSITIONS + 1):
        with pytest.raises(ConfigError, match="truth_positions"):
            ExperimentConfig(truth_positions=bad)


def test_runs_into_one_folder_are_summed_in_the_report_header(tmp_path):
    from rfmitsuba.experiments.report import _runs_line
    from rfmitsuba.experiments.reproduce import record_run

    assert _runs_line(tmp_path) == ""                                  # no run recorded
    record_run(tmp_path, wall_s=8874.0, jobs_run=90, tables=["main", "rx_count"])
    assert _runs_line(tmp_path) == ""                                  # one run: "this run took" says it
    record_run(tmp_path, wall_s=6958.4, jobs_run=69, tables=["main"])
    line = _runs_line(tmp_path)
    assert "made by 2 runs that reached their end, 8874 s (90 jobs) + 6958 s (69 jobs) = 15832 s (4.40 h)" in line
    record_run(tmp_path, wall_s=3600.0, jobs_run=7, tables=["main"], stopped="SystemExit")
    line = _runs_line(tmp_path)
    assert ("made by 3 runs (1 stopped early), 8874 s (90 jobs) + 6958 s (69 jobs) + 3600 s (7 jobs, stopped: "
            "SystemExit) = 19432 s (5.40 h)") in line
    # a running run's row is rewritten in place (by its id), not appended again
    record_run(tmp_path, wall_s=60.0, jobs_run=1, tables=["main"], stopped="no end recorded", run_id="r4")
    record_run(tmp_path, wall_s=120.0, jobs_run=2, tables=["main"], stopped="no end recorded", run_id="r4")
    assert "+ 120 s (2 jobs, stopped: no end recorded) = 19552 s" in _runs_line(tmp_path)
    record_run(tmp_path, wall_s=150.0, jobs_run=3, tables=["main"], run_id="r4")
    assert "made by 4 runs (1 stopped early)" in _runs_line(tmp_path)
    assert "+ 150 s (3 jobs) = 19582 s" in _runs_line(tmp_path)


def test_a_killed_run_records_its_time(monkeypatch, tmp_path):
    """SIGTERM (kill) stops reproduce like Ctrl-C: the run unwinds, and runs.jsonl keeps its wall
    time and the jobs it finished, marked as stopped."""
    import os
    import signal

    from rfmitsuba.experiments import reproduce as R
    from rfmitsuba.experiments.sizes import size_config

    def killed(tasks, *, cluster=None, desc="", unit="", quiet=False, on_result=None):
        os.kill(os.getpid(), signal.SIGTERM)
        raise AssertionError("SIGTERM did not stop the run")

    monkeypatch.setattr(R, "run_tasks", killed)
    before = signal.getsignal(signal.SIGTERM)
    from rfmitsuba.core.interrupt import Terminated

    with pytest.raises(Terminated):
        R.reproduce(tmp_path / "out", size_config("tiny"), quiet=True)
    (row,) = (json.loads(line) for line in (tmp_path / "out" / "runs.jsonl").read_text().splitlines())
    assert row["stopped"] == "Terminated" and row["jobs_run"] == 0 and row["wall_s"] >= 0
    assert signal.getsignal(signal.SIGTERM) == before                 # the handler is restored


def test_a_run_killed_outright_keeps_its_time(tmp_path):
    """SIGKILL (or a lost machine) gives Python no chance to unwind: the run's row of runs.jsonl,
    written at its start and kept current by a heartbeat, still holds its time, marked."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "out"
    script = f"""
import time
from rfmitsuba.experiments import reproduce as R
from rfmitsuba.experiments.sizes import size_config
R.HEARTBEAT_S = 0.2
def busy(tasks, *, cluster=None, desc="", unit="", quiet=False, on_result=None):
    time.sleep(120)
R.run_tasks = busy
R.reproduce({str(out)!r}, size_config("tiny"), quiet=True)
"""
    proc = subprocess.Popen([sys.executable, "-c", script])
    try:
        row, deadline = None, time.monotonic() + 300
        while time.monotonic() < deadline:
            f = out / "runs.jsonl"
            rows = [json.loads(line) for line in f.read_text().splitlines()] if f.is_file() else []
            if rows and rows[-1]["wall_s"] >= 1.0:
                row = rows[-1]
                break
            assert proc.poll() is None, "the run ended by itself"
            time.sleep(0.1)
        assert row is not None, "no heartbeat within 300 s"
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    (kept,) = (json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines())
    from rfmitsuba.experiments.reproduce import NO_END

    assert kept["stopped"] == NO_END and kept["wall_s"] >= 1.0 and kept["jobs_run"] == 0


def test_each_job_waits_for_its_own_datasets_not_for_all(monkeypatch, tmp_path):
    """reproduce submits one graph: the datasets (and truth checks) first, then each job after its
    own dataset(s) and the job it builds on, so on a cluster a job starts while another
    dataset is still being generated."""
    from rfmitsuba.experiments import reproduce as R
    from rfmitsuba.experiments.sizes import size_config

    seen = []

    def fake_run(tasks, *, cluster=None, desc="", unit="", quiet=False, on_result=None):
        seen.append(list(tasks))
        return {t.name: {"fake": t.name} for t in tasks}

    monkeypatch.setattr(R, "run_tasks", fake_run)
    monkeypatch.setattr(R, "write_report", lambda out, cfg, results, *, wall_s: out / "report.md")
    cfg = size_config("tiny")
    R.reproduce(tmp_path / "out", cfg, quiet=True)
    (tasks,) = seen                                                   # one submission
    names = [t.name for t in tasks]
    jobs = R.all_jobs(cfg)
    data = [n for n in names if n.startswith("data/")]
    assert names[:len(data)] == data                                  # datasets first
    by_name = {t.name: t for t in tasks}
    for j in jobs:
        after = by_name[f"{j.dataset.key}/{j.key}"].after
        want = {f"data/{j.dataset.key}"} | ({f"data/{j.eval_dataset.key}"} if j.eval_dataset else set())
        assert want <= set(after) and set(after) - want == (
            {f"{j.dataset.key}/{j.prior_job().key}"} if j.prior_job() else set())
    assert any(j.prior_job() for j in jobs) and any(j.eval_dataset for j in jobs)
    results = json.loads((tmp_path / "out" / "results.json").read_text())
    assert set(results) == {f"{j.dataset.key}/{j.key}" for j in jobs}   # jobs only


def test_datasets_that_do_not_fit_on_the_disk_are_refused_before_anything_is_written(monkeypatch, tmp_path):
    """A file system with less room than the datasets still to generate: a RunError naming the
    folder, the bytes needed and free, and no output folder (the full size needs about 52 GB)."""
    import collections
    import shutil

    from rfmitsuba.core.errors import RunError
    from rfmitsuba.experiments import reproduce as R
    from rfmitsuba.experiments.sizes import size_config

    cfg = size_config("tiny")
    need = R.disk_needed(R.dataset_specs(cfg), cfg, tmp_path / "out" / "data")
    assert need > 0
    assert 50e9 < R.disk_needed(R.dataset_specs(size_config("full")), size_config("full"), tmp_path / "x") < 60e9
    usage = collections.namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10**12, 10**12 - need, need))
    with pytest.raises(RunError, match=r"out/data: the datasets still to generate need about .* GB .* but its file "
                                       r"system has .* GB free; free some space, or give --data"):
        R.reproduce(tmp_path / "out", cfg, quiet=True)
    assert not (tmp_path / "out").exists()


def test_a_bad_override_is_refused_before_anything_is_written(tmp_path):
    """An unknown option in ``train.overrides`` stops the run before ``experiment.toml`` or a dataset is
    written, so the corrected command runs into the same folder."""
    from rfmitsuba.core import config as C
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.experiments import reproduce as R
    from rfmitsuba.experiments.sizes import size_config

    cfg = C.override(size_config("tiny"), ["train.overrides=['threads=1']"])
    with pytest.raises(ConfigError, match="threads"):
        R.reproduce(tmp_path / "out", cfg, quiet=True)
    assert [p.name for p in (tmp_path / "out").iterdir()] == [".lock"]


def test_an_unfinished_job_of_an_older_folder_still_matches_its_configuration():
    """A job.json written before options were removed (members = 1) and before "auto" replaced
    the sentinels (epochs = -1, downsample = 0, starts = 0, jitter = -1) is the same configuration
    as today's; a job of a really other configuration still differs."""
    import copy

    from rfmitsuba.experiments import reproduce as R
    from rfmitsuba.experiments.methods import config_dict
    from rfmitsuba.experiments.sizes import method_config, size_config
    from rfmitsuba.train.config import config_diff

    want = {"job": {"method": "baseline"}, "method_config": json.loads(json.dumps(config_dict(
        method_config(size_config("tiny").train, scene_known=True))))}
    old = copy.deepcopy(want)
    s1 = old["method_config"]["stage1"]
    s1.update(members=1, val_positions="random", epochs=-1.0, starts=0, jitter=-1.0)
    if s1["downsample"] == "auto":
        s1["downsample"] = 0
    assert config_diff(R._saved_job(old), want) == []
    s1["iterations"] += 1
    assert config_diff(R._saved_job(old), want) != []


def test_a_job_record_with_the_old_method_name_reads_as_the_new_one():
    from rfmitsuba.experiments.reproduce import _saved_job

    assert _saved_job({"job": {"method": "baseline_human", "seed": 0}})["job"] == {"method": "baseline_person", "seed": 0}
