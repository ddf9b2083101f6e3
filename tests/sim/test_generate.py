"""Tests of rfmitsuba.sim.generate's exact array (``array="exact"``): the same dataset format,
the option recorded in meta.json, and its limits."""
import json

import numpy as np
import pytest

from rfmitsuba.core.errors import ConfigError, DatasetError
from rfmitsuba.data import store as D
from rfmitsuba.sim import generate as gen
from rfmitsuba.sim.simulate import SolverConfig


def _cfg(xml, **kw):
    return gen.GenerateConfig(scene=str(xml), positions=4, human_positions=0,
                              solver=SolverConfig(samples_per_src=2000, max_depth=1), **kw)


def test_exact_dataset_same_format_recorded_in_meta(variant, box_room, tmp_path):
    from rfmitsuba.sim.simulate import Simulator

    syn = gen.generate(tmp_path / "syn", _cfg(box_room), quiet=True)
    ex = gen.generate(tmp_path / "ex", _cfg(box_room, array="exact"), quiet=True)
    assert ex.meta["generate"]["array"] == "exact"
    assert "array" not in syn.meta["generate"]  # the default: meta as before the option
    assert np.array_equal(ex.antenna_pos, syn.antenna_pos)
    ds = D.open_dataset(ex.path)  # every reader opens it
    assert ds.pas(0).shape == (4, 90, 360) and ds.channel(0).shape == (4, 16)
    s = Simulator(box_room, fixed_pos=ex.fixed_pos, solver=SolverConfig(samples_per_src=2000, max_depth=1))
    s.set_positions(ex.antenna_pos.astype(np.float64))
    assert np.array_equal(ds.channel(0), s.channels("rx", array="exact"))
    assert not np.allclose(ds.channel(0), syn.channel(0))
    # resuming the same configuration does nothing; the synthetic folder is another configuration
    gen.generate(tmp_path / "ex", _cfg(box_room, array="exact"), quiet=True)
    assert len(json.loads((ex.path / "timing.json").read_text())) == 2
    with pytest.raises(DatasetError, match="generate.array"):
        gen.generate(tmp_path / "syn", _cfg(box_room, array="exact"), quiet=True)


def test_exact_array_options_refused(box_room, tmp_path):
    with pytest.raises(ConfigError, match="array must be one of synthetic, exact, got 'bogus'"):
        gen.generate(tmp_path / "a", _cfg(box_room, array="bogus"), quiet=True)
    cfg = _cfg(box_room, array="exact")
    cfg.positions = gen.EXACT_MAX_POSITIONS + 1
    with pytest.raises(ConfigError, match=f"subset of positions: got {gen.EXACT_MAX_POSITIONS + 1}, at most"):
        gen.generate(tmp_path / "b", cfg, quiet=True)
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
