"""Stage 2 person Gaussians: inputs reach both networks, the background stays frozen, state round trip."""
from __future__ import annotations

import numpy as np
import pytest

from rfmitsuba.core.errors import ConfigError


def _fields(variant, *, anchor="person"):
    from rfmitsuba.models.splat import SplatConfig, SplatField
    from rfmitsuba.models.splat_person import SplatPersonConfig, SplatPersonField

    rng = np.random.default_rng(0)
    box = np.array([[0.0, 0.0, 0.0], [4.0, 3.5, 2.8]])
    bg = SplatField.initialize(cfg=SplatConfig(init="random", num_gaussians=40), rng=rng, bounds=(box[0], box[1]))
    walk = np.array([[1.0, 1.0, 0.0], [2.0, 1.5, 0.0], [3.0, 2.0, 0.0]])
    hf = SplatPersonField.near_walk(walk, hcfg=SplatPersonConfig(num_gaussians=12, anchor=anchor), field_cfg=bg.cfg, box=box,
                              rng=rng, seed=3)
    return bg, hf, box


def _inputs(box, person):
    from rfmitsuba.data.samples import person_features

    h = np.asarray(person, np.float64).reshape(-1, 3)
    return np.concatenate([person_features(h, box), h.astype(np.float32)], axis=1)


def test_person_position_changes_geometry_and_signal(variant):
    bg, hf, box = _fields(variant)
    ant = np.array([[2.0, 2.0, 1.2], [2.0, 2.0, 1.2]])
    s = hf.splats(ant, extra=_inputs(box, [[1.0, 1.0, 0.0], [3.0, 2.0, 0.0]]))
    m = np.asarray(s.means.numpy()).reshape(3, 2, -1)
    sig = np.asarray(s.signals.numpy()).reshape(2, -1)
    # anchored at the person: the two views' Gaussians are about 2 m apart along x
    assert np.allclose(m[0, 1] - m[0, 0], 2.0, atol=0.5 + 1e-3)
    assert np.abs(sig[1] - sig[0]).max() > 1e-6  # the EM network sees the person position


def test_a_state_written_with_the_old_names_loads(variant, tmp_path):
    """A state saved when its keys said "human" (``human_config``, ``human_octaves``, anchor
    ``"human"``) loads as the same field (rfmitsuba.core.legacy_names)."""
    import json

    from rfmitsuba.models.base import load_field

    bg, hf, box = _fields(variant)
    state = dict(np.load(hf.save(tmp_path / "h.npz")))
    meta = json.loads(str(state["meta"]))
    meta["human_config"] = meta.pop("person_config")
    meta["human_config"]["human_octaves"] = meta["human_config"].pop("person_octaves")
    meta["human_config"]["anchor"] = "human"
    np.savez(tmp_path / "old.npz", **{**state, "meta": np.array(json.dumps(meta))})
    back = load_field(tmp_path / "old.npz")
    assert back.hcfg == hf.hcfg
    ant, x = np.array([[2.0, 2.0, 1.2]]), _inputs(box, [[2.0, 1.5, 0.0]])
    assert np.array_equal(np.asarray(hf.splats(ant, extra=x).means.numpy()),
                          np.asarray(back.splats(ant, extra=x).means.numpy()))


def test_deformation_network_gets_person_position(variant):
    """World-anchored Gaussians move only through the deformation network, which takes the person position."""
    import drjit as dr

    bg, hf, box = _fields(variant, anchor="world")
    ant = np.array([[2.0, 2.0, 1.2], [2.0, 2.0, 1.2]])
    s = hf.splats(ant, extra=_inputs(box, [[1.0, 1.0, 0.0], [3.0, 2.0, 0.0]]))
    m = np.asarray(s.means.numpy()).reshape(3, 2, -1)
    assert np.abs(m[:, 1] - m[:, 0]).max() > 1e-5
    # gradient of the deformed positions reaches the deformation weights
    w = hf.deform.weights
    dr.enable_grad(w)
    hf.deform.set_weights(w)
    s = hf.splats(ant[:1], extra=_inputs(box, [[1.0, 1.0, 0.0]]))
    dr.backward(dr.sum(s.means.x + s.means.y))
    assert np.abs(np.asarray(dr.grad(w).numpy())).max() > 0


def test_bad_inputs(variant):
    from rfmitsuba.models.splat_person import SplatPersonConfig

    bg, hf, box = _fields(variant)
    with pytest.raises(ValueError, match="person"):
        hf.splats(np.zeros((1, 3)) + 1)
    with pytest.raises(ValueError, match=r"\[B, 22 \+ 3\]"):
        hf.splats(np.zeros((1, 3)) + 1, extra=np.zeros((1, 5), np.float32))
    with pytest.raises(ConfigError, match="anchor"):
        SplatPersonConfig(anchor="nowhere")


def test_state_round_trip(variant, tmp_path):
    from rfmitsuba.models.splat_person import SplatPersonField

    bg, hf, box = _fields(variant)
    hf.save(tmp_path / "h.npz")
    back = SplatPersonField.load(tmp_path / "h.npz")
    ant = np.array([[2.0, 2.0, 1.2]])
    x = _inputs(box, [[2.0, 1.5, 0.0]])
    a, b = hf.splats(ant, extra=x), back.splats(ant, extra=x)
    for k in ("means", "signals", "opacities", "log_scales"):
        assert np.array_equal(np.asarray(getattr(a, k).numpy()), np.asarray(getattr(b, k).numpy()))
    assert back.num_parameters == hf.num_parameters


def test_background_bit_identical_while_stage2_trains(variant, synthetic_ds, tmp_path):
    """Train Stage 2 for a few steps on top of a background: its arrays and file do not change."""
    from rfmitsuba.experiments import methods
    from rfmitsuba.models.splat import SplatField

    mcfg = methods_config(stage1=20, stage2=12)
    methods.train_method("baseline", synthetic_ds, tmp_path / "b", mcfg=mcfg, seed=0)
    f = tmp_path / "b" / "train" / "final" / "field.npz"
    before_bytes = f.read_bytes()
    before = SplatField.load(f).state_dict()
    methods.train_method("ours", synthetic_ds, tmp_path / "o", mcfg=mcfg, seed=0, stage1_dir=tmp_path / "b" / "train")
    assert f.read_bytes() == before_bytes
    model = methods.load_model("ours", tmp_path / "o")
    after = model.fields[0].state_dict()
    for k, v in before.items():
        if k != "meta":
            assert np.array_equal(v, after[k]), k
    # the person field did train (its weights moved from their initial values)
    assert (tmp_path / "o" / "stage2" / "final" / "field.npz").is_file()


def methods_config(*, stage1, stage2):
    from rfmitsuba.core import config as C
    from rfmitsuba.experiments.methods import MethodConfig
    from rfmitsuba.models.splat_person import SplatPersonConfig
    from rfmitsuba.train.config import TrainConfig

    s1 = C.override(TrainConfig(), ['model="splat"', f"iterations={stage1}", "downsample=6", f"val_every={stage1}",
                                    f"checkpoint_every={stage1}", "splat.init='random'", "splat.num_gaussians=150",
                                    "density.enabled=false"])
    return MethodConfig(stage1=s1, stage2_iterations=stage2, person=SplatPersonConfig(num_gaussians=48))
