"""rfmitsuba.eval.locate.search: the grid, the descents (AD, Nelder-Mead) and the fringe hop
recover a known person position, with and without the empty-room reference; one PAS and bad
queries."""
from __future__ import annotations

import numpy as np
import pytest

from rfmitsuba.core.errors import ConfigError, ImageError


def test_locate_recovers_a_known_position(known_model, pas_at, true_feet):
    from rfmitsuba.eval.locate import SearchRegion, locate

    ant = known_model.data.antenna_pos[:8]
    pas = pas_at(known_model, true_feet, ant)
    reg = SearchRegion.of(known_model)
    assert reg.kind == "walk" and reg.free(true_feet[None, :2])[0]
    r = locate(known_model, pas, ant, grid_m=0.3, starts=2, steps=30, search=reg)
    assert r["descent"] == "ad" and r["views"] == 8 and r["reference"] == "none"
    err = np.hypot(*(r["position"][:2] - true_feet[:2]))
    assert err < 0.05, r
    assert r["loss"] <= r["grid_loss"] and r["position"][2] == 0.0
    # Nelder-Mead (what a person field without AD in its position gets), from the same grid
    n = locate(known_model, pas, ant, grid_m=0.3, starts=2, steps=30, descent="nelder_mead", search=reg)
    assert n["descent"] == "nelder_mead" and np.hypot(*(n["position"][:2] - true_feet[:2])) < 0.05, n
    # with the empty room's PAS as the reference the same position comes back
    e = locate(known_model, pas, ant, grid_m=0.3, starts=2, steps=30, search=reg,
               empty=pas_at(known_model, true_feet, ant, person=False))
    assert e["reference"] == "empty" and np.hypot(*(e["position"][:2] - true_feet[:2])) < 0.05, e


def test_one_pas_and_bad_query(known_model, pas_at, true_feet):
    from rfmitsuba.eval.locate import Query, locate

    one = pas_at(known_model, true_feet, known_model.data.antenna_pos[:1])[0]
    r = locate(known_model, one, known_model.data.antenna_pos[0], grid_m=0.5, starts=1, steps=2, descent="none")
    assert r["views"] == 1 and r["descent"] == "none" and r["loss"] == r["grid_loss"]
    with pytest.raises(ImageError, match="90, 360"):
        Query(known_model, np.zeros((2, 45, 180)), known_model.data.antenna_pos[:2])
    with pytest.raises(ConfigError, match="one row per PAS"):
        Query(known_model, np.ones((2, 90, 360)), known_model.data.antenna_pos[:3])
    with pytest.raises(ConfigError, match="region"):
        locate(known_model, one, known_model.data.antenna_pos[0], region="house")
    with pytest.raises(ConfigError, match="names no room"):
        locate(known_model, one, known_model.data.antenna_pos[0], region="room")
