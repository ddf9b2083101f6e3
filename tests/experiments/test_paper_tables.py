"""rfmitsuba.experiments.paper_tables: one object per paper table, its jobs and its section."""
from __future__ import annotations

import pytest

from rfmitsuba.experiments.paper_tables import TABLES, MainTable
from rfmitsuba.experiments.results import LABEL, Claims
from rfmitsuba.experiments.sizes import TABLES as TABLE_NAMES
from rfmitsuba.experiments.sizes import size_config


def _result(job, dyn: float, stat: float) -> tuple[str, dict]:
    part = lambda m: {"model": {"mean": m, "median": m}, "nearest_neighbour": {"mean": 0.5}, "mean_image": {"mean": 0.3}}
    return f"{job.dataset.key}/{job.key}", {"job": job.record(), "train": {"steps": 10, "val_ssim": 0.9},
                                           "eval": {"dynamic": part(dyn), "static": part(stat), "affected": part(dyn)}}


def test_every_named_table_is_one_object_with_jobs_for_each_seed():
    assert tuple(TABLES) == tuple(TABLE_NAMES)
    cfg = size_config("full")
    for key, table in TABLES.items():
        jobs = table.jobs(cfg, 7)
        assert jobs and all(j.seed == 7 for j in jobs), key
        lines = table.section(cfg, {}, Claims())  # nothing run yet: the section still renders
        assert lines[0].startswith("## "), key


@pytest.mark.parametrize("ours", [0.8, 0.6])
def test_main_table_section_and_claims_follow_the_results(ours):
    cfg = size_config("quick")
    results = {}
    for seed in cfg.seeds:
        for job in MainTable().jobs(cfg, seed):
            dyn = {"baseline": 0.7, "end_to_end": 0.65, "ours": ours, "continued": 0.701, "duplicated": 0.692,
                   "baseline_person": 0.703}[job.method] + 0.001 * seed
            results.update([_result(job, dyn, 0.75)])
    claims = Claims()
    text = "\n".join(MainTable().section(cfg, results, claims))
    assert f"{ours + 0.001:.3f} ± 0.001" in text  # mean +- std over the 3 seeds
    # the ablations' methods have a row in every room x task cell
    cells = len(cfg.rooms) * len(cfg.tasks)
    for m, dyn in (("continued", 0.702), ("duplicated", 0.693), ("baseline_person", 0.704)):
        assert text.count(f"| {LABEL[m]} | {dyn:.3f} ± 0.001 |") == cells
    verdicts = "\n".join(claims.rows)
    assert "Ours beats Baseline" in verdicts
    assert ("**holds**" if ours > 0.7 else "**does not hold**") in verdicts.splitlines()[0]
    # Ours against the ablations at its own budget: counted over the cells, dynamic and where
    # the person matters (here both follow the dynamic figure)
    equal = [row for row in claims.rows if "with the same steps" in row]
    assert len(equal) == 6
    want = f"| {cells} of {cells} scene/task pairs | **holds** |" if ours > 0.7 else \
        f"| 0 of {cells} scene/task pairs | **does not hold** |"
    assert all(row.endswith(want) for row in equal), equal


def test_third_stage_table_judges_the_static_scene():
    """Stage 3 above Baseline on every seed by more than the spread -> the walk improves the
    static scene holds; another model family -> no jobs and a section that says why."""
    from rfmitsuba.core import config as C
    from rfmitsuba.experiments.paper_tables import ThirdStageTable

    cfg = size_config("full")
    results = {}
    for seed in cfg.seeds:
        for job in ThirdStageTable().jobs(cfg, seed):
            stat = {"baseline": 0.90, "continued": 0.90, "ours": 0.90, "refined": 0.92}[job.method] + 0.001 * seed
            results.update([_result(job, 0.9, stat)])
    claims = Claims()
    text = "\n".join(ThirdStageTable().section(cfg, results, claims))
    assert "| Ours + Stage 3 | 10 | 0.921 ± 0.001 |" in text
    assert claims.rows[0].startswith("| The walk improves the static scene") and claims.rows[0].endswith("**holds** |")
    splat = C.override(cfg, ["train.model='splat'"])
    assert ThirdStageTable().jobs(splat, 0) == []
    assert "Not run" in "\n".join(ThirdStageTable().section(splat, {}, Claims()))


@pytest.mark.parametrize("spread, verdicts", [(0.0, ("**holds**", "**holds**")),
                                              (0.02, ("**unclear**", "**unclear**"))])
def test_material_order_is_judged_pair_by_pair_on_the_seeds(spread, verdicts):
    """The paper's order concrete > tissue > metal, one paired claim per step: means 0.001 apart
    hold when every seed agrees, and are unclear when the seeds disagree (the spread)."""
    from rfmitsuba.experiments.paper_tables import MaterialTable

    cfg = size_config("full")
    base = {"concrete": 0.904, "tissue": 0.903, "metal": 0.902}
    results = {}
    for seed in cfg.seeds:
        for job in MaterialTable().jobs(cfg, seed):
            jitter = spread * (-1) ** seed if job.dataset.material != "tissue" else 0.0
            results.update([_result(job, base[job.dataset.material] + jitter, 0.9)])
    claims = Claims()
    MaterialTable().section(cfg, results, claims)
    assert len(claims.rows) == 2
    assert claims.rows[0].startswith("| A concrete perturber is easier than tissue for Ours")
    assert claims.rows[1].startswith("| A tissue perturber is easier than metal for Ours")
    for row, verdict in zip(claims.rows, verdicts):
        assert row.endswith(f"{verdict} |"), row


def test_all_jobs_once_grouped_by_dataset_with_each_prior_first():
    from rfmitsuba.experiments.paper_tables import all_jobs, table_jobs

    cfg = size_config("full")
    jobs = all_jobs(cfg)
    names = [f"{j.dataset.key}/{j.key}" for j in jobs]
    assert len(names) == len(set(names))
    wanted = {f"{j.dataset.key}/{j.key}" for t in table_jobs(cfg).values() for j in t}
    assert wanted <= set(names)
    keys = [j.dataset.key for j in jobs]
    runs = [k for i, k in enumerate(keys) if i == 0 or keys[i - 1] != k]
    assert len(runs) == len(set(runs)) > 3  # each dataset's jobs in one run
    pos = {n: i for i, n in enumerate(names)}
    for j, n in zip(jobs, names):
        if j.prior_job() is not None:
            assert pos[f"{j.dataset.key}/{j.prior_job().key}"] < pos[n]


def test_large_room_table_gives_the_fit_gap_and_where_it_breaks(tmp_path):
    """The Baseline's static fit against its test score per room, the seed mean of its breakdown by
    distance, and large_room.png; jobs that predate the breakdown leave those lines out."""
    from rfmitsuba.experiments.paper_tables import LargeRoomTable

    cfg = size_config("full")
    table = LargeRoomTable()
    results = {}
    for seed in cfg.seeds:
        for job in table.jobs(cfg, seed):
            name, r = _result(job, 0.8, 0.85 + 0.01 * seed)
            r["eval"]["static"]["fit"] = {"mean": 0.95}
            r["eval"]["static"]["nearest_neighbour"]["mean"] = 0.6
            b = {"edges": [1.0, 2.0, 4.0], "count": [5, 5], "model": [0.9 - 0.01 * seed, 0.7], "nearest_neighbour": [0.6, 0.5]}
            r["eval"]["static"]["by_distance"] = {"to_fixed_device": b, "to_nearest_training": b}
            results[name] = r
    text = "\n".join(table.section(cfg, results, Claims()))
    # fit 0.95 against test 0.86 +- 0.01: gap +0.090
    assert "| Larger scene (11 x 7.5 m) | 0.950 ± 0.000 | 0.860 ± 0.010 | +0.090 | 0.600 ± 0.000 |" in text
    assert "1.00–2.00 m: **0.890** / 0.600 | 2.00–4.00 m: **0.700** / 0.500" in text
    assert table.figures(tmp_path, cfg, results) and (tmp_path / "large_room.png").is_file()
    for r in results.values():
        del r["eval"]["static"]["by_distance"]
    assert "Where it breaks" not in "\n".join(table.section(cfg, results, Claims()))
    assert table.figures(tmp_path / "none", cfg, results) == []


def test_main_table_places_the_static_figures_against_the_truth_band(tmp_path):
    """The main table's figures hook reads the truth checks of the reproduction folder: one row per
    room and task that has one, the methods' static means beside the band, nothing without a check."""
    import json

    from rfmitsuba.experiments.truth import truth_folder

    cfg = size_config("quick")
    results = {}
    for seed in cfg.seeds:
        for job in MainTable().jobs(cfg, seed):
            stat = {"baseline": 0.92, "end_to_end": 0.93, "ours": 0.92}.get(job.method, 0.95)
            results.update([_result(job, 0.9, stat)])
    assert MainTable().figures(tmp_path, cfg, results) == []          # no check has run
    band = {"mean": 0.925, "median": 0.94, "p10": 0.81, "min": 0.6, "max": 0.99}
    folder = truth_folder(tmp_path, "bedroom", "rx")
    folder.mkdir(parents=True)
    (folder / "summary.json").write_text(json.dumps({
        "count": 48, "solver": {"samples_per_src": 25000}, "stats": {"ssim": band},
        "noise": {"stats": {"ssim": dict(band, mean=0.997)}}}))
    text = "\n".join(MainTable().figures(tmp_path, cfg, results))
    row = next(line for line in text.splitlines() if line.startswith("| Scene 1 (bedroom) | moving RX"))
    assert "| 48 | 0.925 / 0.940 / 0.810 | 0.997 | 0.920 / 0.930 / 0.920 | 1 of 3 |" in row, row
    assert "(truth/bedroom_rx/table.md)" in row
    assert "25000 ray samples per source" in text
    assert "differ by at most 0.010" in text and "at least 0.075 below 1" in text
    assert "moving TX" not in text                                    # its check has not run


def test_data_scarce_table_jobs_share_their_baselines_and_the_test_positions():
    """Every job trains on the long-walk dataset of its room and task, on a grid of static
    positions; Baseline and Continued see no walk, the walk methods the first N positions of it,
    and Ours (every walk length) builds on the one Baseline of its positions."""
    import dataclasses

    from rfmitsuba.experiments.paper_tables import DataScarceTable, all_jobs

    table = DataScarceTable()
    tiny = size_config("tiny")
    jobs = table.jobs(tiny, 0)
    counts, walks = sorted(tiny.scarce_positions), [w for w in sorted(tiny.walk_lengths) if w]
    # splat: no Stage 3, Baseline (person) carries the walk's static figures
    assert table.static_method(tiny) == "baseline_person"
    assert len(jobs) == len(counts) * (2 + 2 * len(walks))
    assert {j.dataset.walk_positions for j in jobs} == {max(tiny.walk_lengths)} and {j.layout for j in jobs} == {"grid"}
    assert {(j.method, j.walk_frames) for j in jobs if j.walk_frames == 0} == {("baseline", 0), ("continued", 0)}
    ours = next(j for j in jobs if j.method == "ours" and j.walk_frames == walks[-1])
    assert ours.prior_job() == dataclasses.replace(ours, method="baseline", walk_frames=0)
    assert ours.key == f"ours_s0_n{ours.positions}_grid_w{walks[-1]}"
    assert "layout" in ours.record() and "layout" not in dataclasses.replace(ours, layout="random").record()
    full = size_config("full")
    assert table.static_method(full) == "refined" and table.one_walk(full) == 35
    fj = table.jobs(full, 0)
    assert len(fj) == 2 * 2 * 6 * (2 + 3 * 4)          # rooms x tasks x static positions x methods per cell
    refined = next(j for j in fj if j.method == "refined")
    assert refined.prior_job().method == "ours" and refined.prior_job().walk_frames == refined.walk_frames
    # named tables only: the defaults leave it out
    assert "data_scarce" not in full.tables
    names = {f"{j.dataset.key}/{j.key}" for j in all_jobs(dataclasses.replace(full, tables=["data_scarce"]))}
    assert len(names) == len(fj) * len(full.seeds)


@pytest.mark.parametrize("gain", [0.03, 0.0])
def test_data_scarce_table_reads_the_break_even_and_says_when_the_walk_never_helps(tmp_path, gain):
    """Made-up results: Baseline climbs 0.60 -> 0.70 -> 0.80 over the static positions; with the walk
    the static score is ``gain`` higher at the scarcest positions. A gain: the bold cell, its worth
    read off the curve and the verdict holds; none: the verdict fails and the page says so. Either
    way the cells below a floor (nearest neighbour 0.65, IDW-3 0.72) are listed with the floors
    they miss."""
    from rfmitsuba.experiments.paper_tables import DataScarceTable

    cfg = size_config("tiny")
    table = DataScarceTable()
    counts = sorted(cfg.scarce_positions)
    curve = dict(zip(counts, (0.60, 0.70, 0.80)))
    results = {}
    for seed in cfg.seeds:
        for job in table.jobs(cfg, seed):
            stat = curve[job.positions] + 0.001 * seed
            if job.method == "baseline_person" and job.positions == counts[0]:
                stat += gain
            name, r = _result(job, 0.7, stat)
            r["eval"]["static"]["nearest_neighbour"]["mean"] = 0.65
            r["eval"]["static"]["idw3"] = {"mean": 0.72}
            r["eval"]["dynamic"]["idw3"] = {"mean": 0.7004}   # above the dynamic 0.7, equal at three digits
            r["train"]["train_time_s"] = 2.0
            results[name] = r
    claims = Claims()
    text = "\n".join(table.section(cfg, results, claims))
    assert "| 4 | 0.601 ± 0.001 |" in text
    verdict_row = next(line for line in text.splitlines() if line.startswith("| Scene 1 (bedroom) | moving RX |"))
    if gain:
        assert f"| **{0.63 + 0.001:.3f} ± 0.001** |" in text
        # 0.63 on the Baseline's curve: 30% of the way from 4 to 8 in log positions
        worth = 4 * 2 ** 0.3 - 4
        assert f"| 4 | {worth:.0f} ± 0 (per seed" in text
        assert "| +0.030 ± 0.000 | **holds** | +0.030 ± 0.000 | **holds** |" in verdict_row
        # beyond more steps (Continued): the gain at the scarcest positions, none elsewhere
        grid = text[text.index("over Continued (the Baseline trained"):]
        assert "| 4 | **+0.030 ± 0.000** | **+0.030 ± 0.000** |" in grid
        assert "| 8 | +0.000 ± 0.000 | +0.000 ± 0.000 |" in grid
        assert "never improves" not in text
    else:
        assert "| 4 | 0 ± 0 (per seed 0, 0, 0) |" in text
        assert verdict_row.endswith("| +0.000 ± 0.000 | **fails** | +0.000 ± 0.000 | **fails** |")
        assert "**The walk never improves the static scene.**" in text
        assert "| 4 | +0.000 ± 0.000 | +0.000 ± 0.000 |" in text[text.index("over Continued (the Baseline trained"):]
    # below both floors at 4 positions, below IDW-3 alone at 8, above both at 16
    assert "- Baseline, walk 0, static: 4 (0.601 < IDW-3 0.720, NN 0.650), 8 (0.701 < IDW-3 0.720)\n" in text
    # a model below a floor that it equals at three digits is printed at four
    assert "- Baseline, walk 0, dynamic: 4 (0.7000 < IDW-3 0.7004), 8 (0.7000 < IDW-3 0.7004)," in text
    assert claims.rows[0].startswith(f"| One {table.one_walk(cfg)}-position walk improves the static scene at 4")
    assert table.figures(tmp_path, cfg, results) and (tmp_path / "data_scarce.png").is_file()
    assert table.figures(tmp_path / "none", cfg, {}) == []
