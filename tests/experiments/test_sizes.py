"""rfmitsuba.experiments.sizes: the one sizes config, its named sizes, and method_config."""
from __future__ import annotations

import pytest

from rfmitsuba.core import config as C
from rfmitsuba.core.errors import ConfigError
from rfmitsuba.experiments.sizes import SIZES, TrainSize, method_config, size_config
from rfmitsuba.train.config import training_downsample


def test_every_named_size_round_trips_and_yields_a_method_config(tmp_path):
    for name in SIZES:
        cfg = size_config(name)
        C.save(cfg, tmp_path / f"{name}.toml")
        assert C.to_dict(C.load(type(cfg), tmp_path / f"{name}.toml")) == C.to_dict(cfg)
        m = method_config(cfg.train, scene_known=cfg.source == "sionna")
        assert m.stage1.model == cfg.train.model and m.stage1.iterations == cfg.train.stage1_iterations
        assert m.stage2_iterations == cfg.train.stage2_iterations and m.stage1.batch_views == cfg.train.batch_views


def test_method_config_maps_sizes_and_applies_overrides_last():
    t = TrainSize(model="splat", num_gaussians=123, person_gaussians=7, downsample=5, room_order=1,
                  overrides=["stage1.splat.num_gaussians=99", "coherent_person.num_points=3"])
    m = method_config(t, scene_known=False)
    assert m.stage1.splat.num_gaussians == 99 and m.person.num_gaussians == 7 and m.coherent_person.num_points == 3
    assert m.stage1.splat.init == "random" and m.stage1.downsample == 5
    assert TrainSize().model == "coherent_gaussians"
    c = method_config(TrainSize(model="coherent", room_order=1, furniture_order=0))
    assert c.stage1.downsample == 1 and c.stage1.coherent.room_order == 1 and c.stage1.coherent.furniture_order == 0
    assert c.stage1.optim.lr_net == pytest.approx(3e-3) and c.stage2_optim.lr_amp == pytest.approx(3e-3)
    with pytest.raises(ConfigError, match="needs datasets with a scene"):
        method_config(TrainSize(model="coherent"), scene_known=False)
    with pytest.raises(ConfigError, match="unknown size"):
        size_config("huge")


def test_coherent_gaussians_size_known_and_unknown_room():
    """train.model = "coherent_gaussians": the resolution the field advises (downsample 0 -> 2,
    whatever the size's splat downsample), known room or not; every method
    accepted (End-to-End trains the joint field), an unknown one named."""
    from rfmitsuba.experiments.compare import CompareConfig

    for known in (True, False):
        m = method_config(TrainSize(model="coherent_gaussians", overrides=["coherent_gaussians_person.num_points=4"]),
                          scene_known=known)
        assert m.stage1.model == "coherent_gaussians" and m.stage1.downsample == "auto"
        assert training_downsample(m.stage1) == 2
        assert m.coherent_gaussians_person.num_points == 4
    assert CompareConfig(train=TrainSize(model="coherent_gaussians")).methods == ["baseline", "end_to_end", "ours"]
    with pytest.raises(ConfigError, match="unknown method 'e2e'"):
        CompareConfig(methods=["e2e"], train=TrainSize(model="coherent_gaussians"))
    assert CompareConfig(methods=["baseline", "ours"], train=TrainSize(model="coherent_gaussians")).methods
    with pytest.raises(ConfigError, match="coherent_gaussians"):
        TrainSize(model="gaussians")
