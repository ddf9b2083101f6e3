"""rfmitsuba.experiments.break_even: static positions a walk is worth, read off made-up curves."""
from __future__ import annotations

import math

import pytest

from rfmitsuba.core.errors import ConfigError
from rfmitsuba.experiments.break_even import equivalent_positions, format_worth, positions_worth, worth_over_seeds


def test_worth_is_read_off_the_static_curve_in_log_positions():
    counts = [10, 100, 1000]
    without = [0.5, 0.7, 0.8]
    # 0.6 lies half way from 10 to 100 in log positions: 10 ** 1.5
    assert positions_worth(counts, without, [0.6, 0.7, 0.8], at=10) == pytest.approx(10 ** 1.5 - 10)
    # 0.75 at 100: half way from 100 to 1000
    assert positions_worth(counts, without, [0.5, 0.75, 0.8], at=100) == pytest.approx(10 ** 2.5 - 100)
    # reached exactly at the next count
    assert positions_worth(counts, without, [0.7, 0.7, 0.8], at=10) == pytest.approx(90)
    # no lift, or a loss: worth nothing
    assert positions_worth(counts, without, [0.5, 0.7, 0.8], at=10) == 0.0
    assert positions_worth(counts, without, [0.4, 0.7, 0.8], at=10) == 0.0
    # beyond the curve
    assert math.isinf(positions_worth(counts, without, [0.9, 0.7, 0.8], at=10))


def test_a_curve_that_dips_is_read_at_its_first_crossing_above_the_start():
    counts = [20, 40, 80, 160]
    without = [0.6, 0.55, 0.7, 0.9]
    # from 40 (0.55) up: 0.65 is first reached between 40 and 80 (the 20 point does not count)
    assert equivalent_positions(counts, without, 0.65, start=1) == pytest.approx(40 * 2 ** (0.10 / 0.15))
    assert equivalent_positions(counts, without, 0.5, start=1) == 40.0
    with pytest.raises(ConfigError, match="ascending"):
        equivalent_positions([20, 10], [0.5, 0.6], 0.55)
    with pytest.raises(ConfigError, match="not one of the counts"):
        positions_worth(counts, without, without, at=30)


def test_worth_over_seeds_gives_the_spread_and_flags_seeds_beyond_the_curve():
    counts = [10, 100]
    without = {0: [0.5, 0.7], 1: [0.5, 0.7], 2: [0.5, 0.7]}
    with_walk = {0: [0.6, 0.7], 1: [0.7, 0.8], 2: [0.5, 0.7]}
    w = worth_over_seeds(counts, without, with_walk, at=10)
    assert w["per_seed"] == pytest.approx({0: 10 ** 1.5 - 10, 1: 90.0, 2: 0.0})
    assert w["mean"] == pytest.approx((10 ** 1.5 - 10 + 90) / 3) and w["std"] > 0 and w["beyond"] == []
    assert format_worth(w) == "37 ± 47 (per seed 22, 90, 0)"
    w = worth_over_seeds(counts, without, {0: [0.9, 0.9], 1: [0.6, 0.7]}, at=10)
    assert w["beyond"] == [0] and math.isnan(w["mean"])
    assert format_worth(w) == "> 90 on 1 of 2 seeds (per seed > 90, 22)"
    assert worth_over_seeds(counts, without, {0: [math.nan, 0.7]}, at=10)["per_seed"] == {}
    assert format_worth(worth_over_seeds(counts, {}, {}, at=10)) == "-"
