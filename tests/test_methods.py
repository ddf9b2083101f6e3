"""The methods registry, training of each kind, and the two evaluations."""
from __future__ import annotations

import numpy as np
import pytest

from rfmitsuba.errors import ConfigError


def _mcfg(stage1, stage2):
    from rfmitsuba import config as C
    from rfmitsuba.human_field import HumanConfig
    from rfmitsuba.methods import MethodConfig
    from rfmitsuba.train import TrainConfig

    s1 = C.override(TrainConfig(), [f"iterations={stage1}", "downsample=6", f"val_every={stage1}",
                                    f"checkpoint_every={stage1}", "field.init='random'", "field.num_gaussians=200",
                                    "density.enabled=false"])
    return MethodConfig(stage1=s1, stage2_iterations=stage2, human=HumanConfig(num_gaussians=60))


def test_registry_and_budgets():
    from rfmitsuba.methods import METHODS, get_method, stage1_config

    assert set(METHODS) == {"baseline", "continued", "duplicated", "baseline_human", "end_to_end", "ours"}
    mc = _mcfg(30, 20)
    assert stage1_config(mc, get_method("baseline"), seed=0).iterations == 30
    for m in ("continued", "duplicated", "baseline_human", "end_to_end"):
        assert stage1_config(mc, get_method(m), seed=0).iterations == 50  # = Ours' two stages
    with pytest.raises(ConfigError, match="unknown method 'nerf'"):
        get_method("nerf")


@pytest.fixture(scope="module")
def trained(synthetic_ds, tmp_path_factory):
    """Baseline (150 steps), Ours (+150 Stage-2 steps) and End-to-End on the synthetic dataset."""
    from rfmitsuba import methods

    root = tmp_path_factory.mktemp("methods")
    mc = _mcfg(150, 150)
    methods.train_method("baseline", synthetic_ds, root / "baseline", mcfg=mc, seed=0)
    methods.train_method("ours", synthetic_ds, root / "ours", mcfg=mc, seed=0, stage1_dir=root / "baseline" / "train")
    return root


def test_two_stage_beats_frozen_background(trained, synthetic_ds):
    """Same frozen background with and without the human Gaussians, on unseen antennas x unseen humans."""
    from rfmitsuba import methods

    ours = methods.evaluate(methods.Model.load("ours", trained / "ours"), synthetic_ds)
    bg = methods.evaluate(methods.Model.load("baseline", trained / "baseline"), synthetic_ds)
    assert ours["dynamic"]["model"]["mean"] > bg["dynamic"]["model"]["mean"] + 0.03
    # static: the human Gaussians are off in the empty room -> exactly the background
    assert ours["static"]["model"]["mean"] == bg["static"]["model"]["mean"]
    for part in ("dynamic", "static"):
        assert {"model", "nearest_neighbour", "mean_image"} <= set(ours[part])
        assert ours[part]["test_samples"] > 0
    assert ours["render_ms_per_pas"] > 0


def test_end_to_end_takes_the_human_position(synthetic_ds, tmp_path):
    from rfmitsuba import methods
    from rfmitsuba.samples import SampleData

    mc = _mcfg(10, 5)
    s = methods.train_method("end_to_end", synthetic_ds, tmp_path / "e", mcfg=mc, seed=1)
    assert s["steps"] == 15
    model = methods.Model.load("end_to_end", tmp_path / "e")
    assert model.fields[0].extra_inputs > 0
    data = SampleData.open_samples(synthetic_ds, states="all")
    a = data.antennas
    k1 = np.flatnonzero((a == a[data.test[0]]) & (data.states == 1))
    k2 = np.flatnonzero((a == a[data.test[0]]) & (data.states == 5))
    img = model.render(data, np.concatenate([k1, k2]), batch=2)
    assert np.abs(img[0] - img[1]).max() > 1e-6


def test_missing_stage1(synthetic_ds, tmp_path):
    from rfmitsuba import methods
    from rfmitsuba.errors import RunError

    with pytest.raises(RunError, match="has not finished"):
        methods.train_method("ours", synthetic_ds, tmp_path / "o", mcfg=_mcfg(5, 5), stage1_dir=tmp_path / "nothing")
