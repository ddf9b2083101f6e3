"""rfmitsuba.experiments.results: selecting jobs and the paired verdicts on claims."""
from __future__ import annotations

import pytest

from rfmitsuba.experiments.job import Job
from rfmitsuba.experiments.results import DYN, Claims, select
from rfmitsuba.experiments.sizes import DatasetSpec


def _rows(method: str, scores: dict, **kw) -> list[dict]:
    return [{"job": Job(DatasetSpec("bedroom", "rx", **kw), method, s).record(),
             "eval": {"dynamic": {"model": {"mean": v}}}} for s, v in scores.items()]


@pytest.mark.parametrize("a, b, verdict", [
    ({0: 0.80, 1: 0.82, 2: 0.81}, {0: 0.78, 1: 0.79, 2: 0.80}, "**holds**"),         # +0.02 +0.03 +0.01
    ({0: 0.80, 1: 0.78, 2: 0.81}, {0: 0.78, 1: 0.79, 2: 0.80}, "**unclear**"),       # +0.02 -0.01 +0.01
    ({0: 0.77, 1: 0.78, 2: 0.79}, {0: 0.78, 1: 0.79, 2: 0.80}, "**does not hold**"),  # all -0.01
    ({0: 0.90}, {0: 0.80}, "**unclear**"),                                            # one seed
    ({0: 0.80, 1: 0.81}, {2: 0.70}, "n/a (not run)"),                                 # no common seed
])
def test_paired_verdicts(a, b, verdict):
    c = Claims()
    c.paired("A beats B", "-", _rows("ours", a), _rows("baseline", b), DYN, names=("A", "B"))
    (row,) = c.rows
    assert row.endswith(f"| {verdict} |"), row
    if verdict != "n/a (not run)":
        assert "effect " in row and "per seed" in row


def test_paired_effect_and_spread_are_over_common_seeds():
    c = Claims()
    c.paired("A beats B", "-", _rows("ours", {0: 0.9, 1: 0.8, 5: 0.1}), _rows("baseline", {0: 0.85, 1: 0.78}), DYN,
             names=("A", "B"))
    assert "A 0.850 vs B 0.815: effect +0.035 ± 0.021 over 2 seeds (per seed +0.050, +0.020)" in c.rows[0]


def test_one_common_seed_has_no_spread_in_the_text():
    c = Claims()
    c.paired("A beats B", "-", _rows("ours", {0: 0.9}), _rows("baseline", {0: 0.85}), DYN, names=("A", "B"))
    assert "effect +0.050 over 1 seeds" in c.rows[0] and "nan" not in c.rows[0]
    assert c.rows[0].endswith("| **unclear** |")


def test_select_tells_where_a_job_was_evaluated():
    main, extra = DatasetSpec("bedroom", "rx"), DatasetSpec("bedroom", "rx", static_positions=7500)
    r = {"a": {"job": Job(extra, "baseline", 0, positions=1800, eval_dataset=main).record()},
         "b": {"job": Job(extra, "baseline", 0, positions=1800).record()},
         "c": {"job": Job(main, "baseline", 0).record()}}
    assert select(r, dataset=extra.key, method="baseline", positions=1800, eval_dataset=main.key) == [r["a"]]
    assert select(r, dataset=extra.key, method="baseline", positions=1800) == [r["b"]]
    assert select(r, dataset=main.key, method="baseline") == [r["c"]]
    assert "eval_dataset" not in r["c"]["job"] and extra.key == "bedroom_rx_tissue_static7500"
