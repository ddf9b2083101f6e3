"""rfmitsuba.experiments.compare: methods over seeds on one dataset, resumable, refuses other sizes."""
from __future__ import annotations

import json
import math

import pytest
from job_metrics import age_metrics

from rfmitsuba.core.errors import ConfigError, RunError


def tiny_compare_cfg(**over):
    from rfmitsuba.core import config as C
    from rfmitsuba.experiments.compare import CompareConfig

    sets = ["methods=['baseline','ours']", "seeds=[0]", "train.stage1_iterations=8", "train.val_every=8",
            "train.stage2_iterations=6", "train.room_order=1", "train.furniture_order=0",
            "train.overrides=['coherent_person.num_points=4']"]
    return C.override(CompareConfig(), sets + [f"{k}={v}" for k, v in over.items()])


def test_compare_report_resume_and_more_seeds(quick_dataset, tmp_path):
    from rfmitsuba.experiments.compare import compare

    out = tmp_path / "cmp"
    rep = compare(quick_dataset.path, out, cfg=tiny_compare_cfg(), progress=False)
    text = rep.read_text()
    assert "| Baseline |" in text and "| Ours (two-stage) |" in text and "Dynamic evaluation" in text
    assert (out / "speed_accuracy.png").is_file() and "![validation SSIM against cumulative training time]" in text
    assert "time to within 0.005 (s)" in text and "| ds | Ours (two-stage) | 1 |" in text  # the dataset folder: ds
    done = {p: p.stat().st_mtime_ns for p in out.glob("seed*/*/DONE")}
    assert len(done) == 2
    # the same command again trains nothing; a second seed adds its jobs and keeps the first
    compare(quick_dataset.path, out, cfg=tiny_compare_cfg(seeds="[0, 1]"), progress=False)
    assert all(p.stat().st_mtime_ns == t for p, t in done.items())
    res = json.loads((out / "results.json").read_text())
    assert sorted((r["method"], r["seed"]) for r in res) == [("baseline", 0), ("baseline", 1), ("ours", 0),
                                                              ("ours", 1)]
    with pytest.raises(RunError, match="another comparison"):
        compare(quick_dataset.path, out, cfg=tiny_compare_cfg(**{"train.stage2_iterations": 7}), progress=False)
    # --reevaluate: metrics of an older evaluation (no "affected" part) are evaluated again, nothing retrains
    mfile = out / "seed1" / "ours" / "metrics.json"
    old = age_metrics(mfile)
    ckpt = {p: p.stat().st_mtime_ns for p in out.glob("seed*/*/**/*.npz")}
    assert ckpt
    compare(quick_dataset.path, out, cfg=tiny_compare_cfg(seeds="[0]"), progress=False, reevaluate=True)
    new = json.loads(mfile.read_text())
    assert "affected" in new["eval"]
    assert new["eval"]["dynamic"]["model"]["mean"] == pytest.approx(old["eval"]["dynamic"]["model"]["mean"], abs=1e-3)
    assert new["train"] == old["train"]
    assert all(p.stat().st_mtime_ns == t for p, t in ckpt.items())
    assert len(json.loads((out / "results.json").read_text())) == 4  # seed 1 kept, re-evaluated too


def test_a_comparison_written_with_the_old_method_name_resumes_without_training(quick_dataset, tmp_path):
    """A folder whose Baseline (person) job is ``seed0/baseline_human`` (the method's name before)
    resumes: nothing trains again and the results name the method as it is called now."""
    from rfmitsuba.experiments.compare import compare

    out = tmp_path / "cmp"
    cfg = tiny_compare_cfg(methods="['baseline_person']")
    compare(quick_dataset.path, out, cfg=cfg, progress=False)
    (out / "seed0" / "baseline_person").rename(out / "seed0" / "baseline_human")
    for f in (out / "compare.toml", out / "seed0" / "baseline_human" / "metrics.json"):
        f.write_text(f.read_text().replace("baseline_person", "baseline_human"))
    done = {p: p.stat().st_mtime_ns for p in out.glob("seed*/*/DONE")}
    compare(quick_dataset.path, out, cfg=cfg, progress=False)
    assert {p: p.stat().st_mtime_ns for p in out.glob("seed*/*/DONE")} == done
    assert [r["method"] for r in json.loads((out / "results.json").read_text())] == ["baseline_person"]
    assert not (out / "seed0" / "baseline_person").exists()
    with pytest.raises(ConfigError, match="'baseline_human': this value is called 'baseline_person' now"):
        tiny_compare_cfg(methods="['baseline_human']")


def test_a_bad_override_leaves_the_folder_as_it_was(quick_dataset, tmp_path):
    """An unknown option in ``train.overrides`` is refused before the comparison writes anything, so
    the corrected command runs into the same folder."""
    from rfmitsuba.experiments.compare import compare

    out = tmp_path / "cmp"
    with pytest.raises(ConfigError, match="threads"):
        compare(quick_dataset.path, out, cfg=tiny_compare_cfg(**{"train.overrides": "['threads=1']"}), progress=False)
    assert not out.exists() or [p.name for p in out.iterdir()] == [".lock"]


def test_compare_config_errors():
    with pytest.raises(ConfigError, match="TrainSize.model"):
        tiny_compare_cfg(**{"train.model": "'nerf'"})
    with pytest.raises(ConfigError, match="nope"):
        from rfmitsuba.experiments.sizes import method_config

        method_config(tiny_compare_cfg(**{"train.overrides": "['stage1.nope=1']"}).train)
    with pytest.raises(ConfigError, match="unknown method"):
        tiny_compare_cfg(methods="['nope']")
    with pytest.raises(ConfigError, match="repeat"):
        tiny_compare_cfg(seeds="[0, 0]")


#: keys of a job's metrics that are wall times (differ between any two runs) or run folders
_TIMES = {"train_time_s", "stage1_train_time_s", "wall_s", "render_ms_per_pas", "runs"}


def _no_times(x):
    if isinstance(x, dict):
        return {k: _no_times(v) for k, v in x.items() if k not in _TIMES}
    if isinstance(x, list):
        return [_no_times(v) for v in x]
    return x


def _flat(x, key=""):
    """``{path: leaf}`` of a nested JSON value."""
    if isinstance(x, dict):
        return {k2: v for k, v in x.items() for k2, v in _flat(v, f"{key}/{k}").items()}
    if isinstance(x, list):
        return {k2: v for i, v in enumerate(x) for k2, v in _flat(v, f"{key}/{i}").items()}
    return {key: x}


def _assert_same_results(actual, desired):
    """Equal to the last bit on LLVM. On CUDA, where gradients are summed with atomics in no fixed
    order so that a job differs from itself between runs (docs/limits.md, run-to-run spread), every count and
    name equal and every float within 1e-4 (absolute) or 1e-3 (relative); two seeds differ by far
    more (the test checks that too)."""
    from rfmitsuba.core import backend as B

    a, d = _flat(_no_times(actual)), _flat(_no_times(desired))
    if not B.is_cuda():
        assert a == d
        return
    assert a.keys() == d.keys()
    worst = max((abs(a[k] - d[k]) for k in a if isinstance(a[k], float)), default=0.0)
    print(f"CUDA: largest difference of a result from the serial run's: {worst:.3g}")
    for k in a:
        if isinstance(a[k], float) and isinstance(d[k], float):
            assert math.isclose(a[k], d[k], rel_tol=1e-3, abs_tol=1e-4), (k, a[k], d[k])
        else:
            assert a[k] == d[k], k


def test_compare_on_local_cluster_matches_serial(quick_dataset, one_thread, tmp_path):
    """The tiny comparison of tests/experiments/test_compare.py, serially (Dr.Jit on one
    thread, as in each worker) and on a LocalCluster of 2 single-thread workers: the same
    metrics to the last bit (on LLVM; see :func:`_assert_same_results`), every job done once, and a
    second run resumes (trains nothing)."""
    from rfmitsuba.core.cluster import ClusterConfig
    from rfmitsuba.experiments.compare import compare

    cfg = tiny_compare_cfg(seeds="[0, 1]")
    compare(quick_dataset.path, tmp_path / "serial", cfg=cfg, progress=False)
    compare(quick_dataset.path, tmp_path / "dask", cfg=cfg, progress=False, cluster=ClusterConfig(workers=2))
    ser = json.loads((tmp_path / "serial" / "results.json").read_text())
    par = json.loads((tmp_path / "dask" / "results.json").read_text())
    assert [(r["method"], r["seed"]) for r in par] == [("baseline", 0), ("ours", 0), ("baseline", 1), ("ours", 1)]
    _assert_same_results(par, ser)
    assert par[0]["eval"]["dynamic"]["model"]["mean"] != par[2]["eval"]["dynamic"]["model"]["mean"]  # seeds differ
    done = {p: p.stat().st_mtime_ns for p in (tmp_path / "dask").glob("seed*/*/DONE")}
    assert len(done) == 4
    compare(quick_dataset.path, tmp_path / "dask", cfg=cfg, progress=False)
    assert all(p.stat().st_mtime_ns == t for p, t in done.items())


def test_ours_every_person_draws_both_people_of_a_two_person_walk(two_people_dataset, tmp_path):
    """Ours (every person) on a walk of two people: its person field takes both people's feet (F + 6
    extra inputs) and is evaluated beside Ours, whose field sees person 1 alone."""
    from rfmitsuba.data.samples import num_person_features
    from rfmitsuba.experiments.compare import compare
    from rfmitsuba.models.base import load_field

    out = tmp_path / "cmp"
    compare(two_people_dataset.path, out, cfg=tiny_compare_cfg(methods="['ours', 'ours_people']"), progress=False)
    f = load_field(out / "seed0" / "ours_people" / "stage2" / "final" / "field.npz")
    one = load_field(out / "seed0" / "ours" / "stage2" / "final" / "field.npz")
    assert f.people == 2 and one.people == 1
    assert f.extra_inputs == num_person_features(f.feature_octaves) + 6
    res = {r["method"]: r for r in json.loads((out / "results.json").read_text())}
    assert all(math.isfinite(res[m]["eval"]["dynamic"]["model"]["mean"]) for m in ("ours", "ours_people"))
    assert "Ours (every person)" in (out / "report.md").read_text()
    # the headline figures the results pages read
    from rfmitsuba.experiments.compare import summary_by_method, summary_table

    summary = summary_by_method(out, ("ours", "ours_people"))
    assert summary["seeds"] == [0] and summary["ours_people"]["dynamic"] == [res["ours_people"]["eval"]["dynamic"]
                                                                            ["model"]["mean"]]
    assert len(summary_table(summary, {"ours": "Ours", "ours_people": "every person"})) == 2 + 2 + 4
    with pytest.raises(RunError, match="no finished jobs of baseline"):
        summary_by_method(out, ("ours", "baseline"))
