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
    return gen.GenerateConfig(scene=str(xml), positions=4, person_positions=0,
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


def test_a_state_is_beamformed_and_written_block_by_block(variant, box_room, tmp_path, monkeypatch):
    """``PAS_BLOCK`` images at a time (here 3 of 10, the last block short): the chunk files are
    those of one block holding the whole state, byte for byte, and its timing names both parts."""
    cfg = gen.GenerateConfig(scene=str(box_room), positions=10, person_positions=1,
                             solver=SolverConfig(samples_per_src=2000, max_depth=1))
    whole = gen.generate(tmp_path / "whole", cfg, quiet=True)
    monkeypatch.setattr(gen, "PAS_BLOCK", 3)
    blocks = gen.generate(tmp_path / "blocks", cfg, quiet=True)
    for s in range(2):
        for name in ("pas.npy", "channel.npy", "chunk.json"):
            a = whole.path / "chunks" / D.chunk_name(s) / name
            assert a.read_bytes() == (blocks.path / "chunks" / D.chunk_name(s) / name).read_bytes(), (s, name)
    timing = json.loads((blocks.path / "timing.json").read_text())[-1]
    assert timing["pas_s"] > 0 and timing["write_s"] > 0 and timing["states"] == 2


def test_blocks_that_do_not_add_up_leave_no_chunk(tmp_path):
    """A generator of images that stops short: a DatasetError naming the state, and no chunk or
    temporary folder left (a resumed run simulates the state again)."""
    root = tmp_path / "ds"
    channel = np.ones((5, 16), np.complex64)
    with pytest.raises(DatasetError, match="state 2: pas.npy: the blocks hold 3 rows, expected 5"):
        D.write_chunk(root, 2, pas_blocks=iter([np.zeros((3, 90, 360), np.float32)]), channel=channel)
    assert list((root / "chunks").iterdir()) == []
    with pytest.raises(DatasetError, match="pas_blocks needs the channel"):
        D.write_chunk(root, 2, pas_blocks=iter([]))
    with pytest.raises(DatasetError, match="give pas or pas_blocks"):
        D.write_chunk(root, 2, channel=channel)


def test_two_people_walk_apart_and_the_antennas_keep_clear_of_both(two_people_dataset, quick_dataset):
    """``people = 2``: a second walk that never comes within the bodies' radii plus 0.1 m of the
    first at one frame, antennas clear of both walks, and a one-person dataset's record unchanged
    (no ``people`` key)."""
    from rfmitsuba.sim import person
    from rfmitsuba.sim.generate import PEOPLE_GAP_M

    ds = two_people_dataset
    assert ds.people_pos.shape == (ds.num_states, 2, 3)
    np.testing.assert_array_equal(ds.people_pos[:, 0], ds.person_pos)
    p = ds.people_pos[1:]
    assert np.hypot(*(p[:, 0, :2] - p[:, 1, :2]).T).min() >= 2 * person.radius() + PEOPLE_GAP_M
    below = ds.antenna_pos[:, None, 2] < person.HEIGHT + 0.1
    d = np.hypot(*(ds.antenna_pos[:, None, :2] - p.reshape(-1, 3)[None, :, :2]).transpose(2, 0, 1))
    assert not np.any((d < person.radius()) & below)
    assert ds.meta["generate"]["people"] == 2 and "people" not in quick_dataset.meta["generate"]
    assert len(ds.meta["other_people"]["positions"]) == ds.num_states - 1
    assert quick_dataset.people_pos.shape == (quick_dataset.num_states, 1, 3)


def test_a_states_job_draws_every_persons_body():
    from rfmitsuba.sim.generate import StatesJob
    from rfmitsuba.sim import person

    one = person.person_mesh([1.0, 1.0, 0.0], 0.0)
    job = StatesJob(root=None, xml=None, task="rx", frequency_hz=2.4e9, material="tissue", scattering_coefficient=0.3,
                    solver=None, fixed_pos=np.zeros(3), antenna_pos=np.zeros((1, 3), np.float32),
                    walk_positions=np.array([[1.0, 1.0, 0.0]]), walk_headings=np.zeros(1),
                    other_positions=np.array([[[2.5, 1.0, 0.0]]]), other_headings=np.zeros((1, 1)))
    both = job.bodies(1)
    assert len(both.vertices) == 2 * len(one.vertices) and len(both.faces) == 2 * len(one.faces)
    assert both.vertices[:, 0].max() > 2.5 > one.vertices[:, 0].max()
