"""rfmitsuba.eval.locate.fingerprint_floor: the training state whose PAS are most like the query's."""
from __future__ import annotations

import numpy as np
import pytest


def test_a_states_own_pas_find_that_state(known_model):
    """Queried with one walk state's own measured PAS at three antennas, the floor returns that
    state, its person position and SSIM 1; asked among the other states only, another one with a
    lower SSIM."""
    from rfmitsuba.eval.locate import fingerprint
    from rfmitsuba.rf.bartlett_ref import normalize

    data = known_model.data
    states = np.unique(data.states[data.states > 0])
    assert len(states) >= 3
    s = int(states[1])
    antennas = np.array([0, 1, 2])
    rows = [int(np.flatnonzero((data.states == s) & (data.antennas == a))[0]) for a in antennas]
    query = normalize(data.pas(np.asarray(rows)))
    hit = fingerprint(data, query, antennas, states=states)
    assert hit["state"] == s and hit["ssim"] == pytest.approx(1.0, abs=1e-5)
    assert np.allclose(hit["position"], data.person_pos[rows[0]])
    other = fingerprint(data, query, antennas, states=states[states != s])
    assert other["state"] != s and other["ssim"] < hit["ssim"]
