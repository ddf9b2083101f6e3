"""Tests of rfmitsuba.models.nn.hash_grid: the hash-grid encoding."""
from __future__ import annotations


def test_hashgrid_network_runs_and_has_parameters(variant):
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.nn import EMNetwork, NetConfig

    cfg = NetConfig(encoding="hashgrid", width=8, hash_levels=2, hash_log2_size=8)
    net = EMNetwork(cfg, seed=0)
    assert "hash" in net.modules() and net.modules()["hash"].num_parameters > 0
    p = [B.Float([0.1, 0.9])] * 3
    s, a, d = net(p, [B.Float([0.5])] * 3)
    assert s.numpy().shape == (2,)
