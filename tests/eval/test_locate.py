"""rfmitsuba.eval.locate and ``rfmitsuba locate``: device-free localisation with a two-stage model.

A known background and person field render the PAS of a person at a known position; locate
recovers it (AD descent, Nelder-Mead, with and without the empty-room reference). Then the
command on a tiny trained comparison, and bad input named."""
from __future__ import annotations

import json

import numpy as np
import pytest

from rfmitsuba.core.errors import ConfigError, DatasetError, ImageError, RunError


@pytest.fixture(scope="module")
def known_model(synthetic_ds, variant):
    """A two-stage model of known fields on the synthetic dataset's geometry: a background of the
    direct path, one wall reflection and two scatterers; a person who blocks strongly and carries
    three scatterers."""
    from rfmitsuba.data.samples import SampleData
    from rfmitsuba.eval.locate import TwoStage
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField
    from rfmitsuba.models.coherent_gaussians_person import CoherentGaussianPersonConfig, CoherentGaussianPersonField

    data = SampleData.open_samples(synthetic_ds, states="all")
    A = np.stack([np.eye(3), np.diag([-1.0, 1.0, 1.0])])
    bg = CoherentGaussianField(A, np.array([0, 1]), np.array([[1.0, 2.5, 2.0], [3.2, 0.4, 0.5]]),
                               cfg=CoherentGaussianConfig(init_extent=1.5), readout="amplitude", wavefront="spherical",
                               vis_center=np.array([2.0, 1.75, 1.0]), frequency_hz=float(data.frequency_hz), seed=0)
    bg.freeze()
    pcfg = CoherentGaussianPersonConfig(num_points=3, person_octaves=1, init_gain=0.5, init_strength=0.9,
                                        init_block_radius=0.3)
    person = CoherentGaussianPersonField.for_background(bg, cfg=pcfg, seed=1)
    person.freeze()
    train = np.isin(data.states, np.asarray(data.split.person_train) + 1) & (data.antennas == 0)
    return TwoStage(background=bg, person=person, data=data, feet_z=0.0, walk=data.person_pos[train], job=synthetic_ds)


def _pas_at(model, feet, antenna_pos, *, person=True):
    """The model's raw PAS float32 [K, 90, 360] with the person's feet at ``feet`` (or no person)."""
    import drjit as dr

    from rfmitsuba.eval.predict import views_at
    from rfmitsuba.models.base import render

    views = views_at(model.data, antenna_pos)
    ext = model.features(np.tile(feet, (len(antenna_pos), 1)))
    views.inputs = lambda field: ext
    fields = [model.background, model.person] if person else [model.background]
    with dr.suspend_grad():
        img = render(fields, views, height=90, width=360, normalize=False)
    return np.asarray(img.numpy(), np.float32).reshape(-1, 90, 360)


TRUE_FEET = np.array([1.9, 1.7, 0.0])


def test_locate_recovers_a_known_position(known_model):
    from rfmitsuba.eval.locate import SearchRegion, locate

    ant = known_model.data.antenna_pos[:8]
    pas = _pas_at(known_model, TRUE_FEET, ant)
    reg = SearchRegion.of(known_model)
    assert reg.kind == "walk" and reg.free(TRUE_FEET[None, :2])[0]
    r = locate(known_model, pas, ant, grid_m=0.3, starts=2, steps=30, search=reg)
    assert r["descent"] == "ad" and r["views"] == 8 and r["reference"] == "none"
    err = np.hypot(*(r["position"][:2] - TRUE_FEET[:2]))
    assert err < 0.05, r
    assert r["loss"] <= r["grid_loss"] and r["position"][2] == 0.0
    # Nelder-Mead (what a person field without AD in its position gets), from the same grid
    n = locate(known_model, pas, ant, grid_m=0.3, starts=2, steps=30, descent="nelder_mead", search=reg)
    assert n["descent"] == "nelder_mead" and np.hypot(*(n["position"][:2] - TRUE_FEET[:2])) < 0.05, n
    # with the empty room's PAS as the reference the same position comes back
    e = locate(known_model, pas, ant, grid_m=0.3, starts=2, steps=30, search=reg,
               empty=_pas_at(known_model, TRUE_FEET, ant, person=False))
    assert e["reference"] == "empty" and np.hypot(*(e["position"][:2] - TRUE_FEET[:2])) < 0.05, e


def test_ad_gradient_matches_finite_differences(known_model, one_thread):
    from rfmitsuba.eval.locate import Query

    ant = known_model.data.antenna_pos[:3]
    q = Query(known_model, _pas_at(known_model, TRUE_FEET, ant), ant, downsample=3)
    xy = TRUE_FEET[None, :2] + [[0.12, -0.08]]
    _, g = q.loss_and_grad(xy)
    h = 1e-3
    fd = [(q.losses(xy + d)[0] - q.losses(xy - d)[0]) / (2 * h) for d in (np.array([[h, 0]]), np.array([[0, h]]))]
    # the min-max normalisation's extreme pixels switch within millimetres, so the finite
    # differences scatter by some 20% along x: direction and size, not digits
    cos = float(g[0] @ fd / np.linalg.norm(g[0]) / np.linalg.norm(fd))
    assert cos > 0.98 and 0.7 < np.linalg.norm(g[0]) / np.linalg.norm(fd) < 1.3, (g, fd)
    step = 2e-3 * g / np.linalg.norm(g)
    assert q.losses(xy - step)[0] < q.losses(xy)[0] < q.losses(xy + step)[0]


def test_one_pas_and_bad_query(known_model):
    from rfmitsuba.eval.locate import Query, locate

    one = _pas_at(known_model, TRUE_FEET, known_model.data.antenna_pos[:1])[0]
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


def test_failure_proxies_blocked_path():
    from rfmitsuba.eval.locate import failure_proxies

    y = np.array([[0.0, 0.0, 1.0]] * 2)
    x = np.array([[4.0, 0.0, 1.0], [0.0, 4.0, 1.0]])
    p = failure_proxies(np.array([2.0, 0.1, 0.0]), x, y)
    assert p["blocked_share"] == 0.5 and p["hidden_from_tx"] is None
    assert p["distance_to_array_m"] == pytest.approx(np.hypot(2.0, 0.1))


@pytest.fixture(scope="module")
def tiny_two_stage(synthetic_ds, tmp_path_factory, variant):
    """A tiny comparison folder (Baseline + Ours, one seed) on the synthetic dataset."""
    from rfmitsuba.core import config as C
    from rfmitsuba.experiments.compare import CompareConfig, compare

    out = tmp_path_factory.mktemp("locate_cmp") / "cmp"
    cfg = C.override(CompareConfig(), ["methods=['baseline','ours']", "seeds=[0]", "train.stage1_iterations=6",
                                       "train.val_every=6", "train.stage2_iterations=4"])
    compare(synthetic_ds, out, cfg=cfg, progress=False)
    return out


def _cli(*argv):
    from rfmitsuba.cli import main

    return main(["locate", *argv])


def test_cli_scores_the_held_out_walk_and_one_query(tiny_two_stage, tmp_path, capsys):
    out = tmp_path / "loc"
    fast = ["--views", "3", "--grid", "0.6", "--starts", "1", "--steps", "2", "--downsample", "6", "--quiet"]
    assert _cli(str(tiny_two_stage), "--out", str(out), *fast) == 0
    res = json.loads((out / "locate.json").read_text())
    assert res["jobs"] == ["seed0"] and len(res["truth"]) == len(res["states"]) >= 1
    for key in ("model", "fingerprint", "walk_centroid"):
        assert res["stats"][key]["n"] >= 1 and np.isfinite(res["stats"][key]["median_cm"])
    assert (out / "locate.png").is_file() and "fingerprint" in (out / "report.md").read_text()
    # one query: the PAS of one held-out state at three antennas, given as files
    from rfmitsuba.data.samples import SampleData

    d = SampleData.open_samples(res["dataset"], states="all")
    s = res["states"][0]
    rows = np.flatnonzero(d.states == s)[:3]
    np.save(tmp_path / "q.npy", d.pas(rows))
    np.save(tmp_path / "pos.npy", d.antenna_pos[rows])
    capsys.readouterr()
    assert _cli(str(tiny_two_stage / "seed0" / "ours"), "--pas", str(tmp_path / "q.npy"), "--positions",
                str(tmp_path / "pos.npy"), "--out", str(tmp_path / "one"), *fast[2:]) == 0
    assert "ours: person at x =" in capsys.readouterr().out
    one = json.loads((tmp_path / "one" / "locate.json").read_text())
    assert len(one["estimates"]) == 1 and len(one["estimates"][0]["position"]) == 3


def test_cli_names_bad_input(tiny_two_stage, tmp_path, capsys):
    assert _cli(str(tiny_two_stage / "seed0" / "baseline"), "--out", str(tmp_path / "a")) == 2
    assert "not a two-stage job" in capsys.readouterr().err
    assert _cli(str(tmp_path), "--out", str(tmp_path / "b")) == 2
    assert "holds no two-stage job" in capsys.readouterr().err
    ours = str(tiny_two_stage / "seed0" / "ours")
    np.save(tmp_path / "bad.npy", np.zeros((2, 90, 180), np.float32))
    np.save(tmp_path / "pos.npy", np.zeros((2, 3)))
    assert _cli(ours, "--pas", str(tmp_path / "bad.npy"), "--positions", str(tmp_path / "pos.npy")) == 2
    assert "90, 360" in capsys.readouterr().err
    np.save(tmp_path / "good.npy", np.ones((2, 90, 360), np.float32))
    (tmp_path / "pos.txt").write_text("1 2\n")
    assert _cli(ours, "--pas", str(tmp_path / "good.npy"), "--positions", str(tmp_path / "pos.txt")) == 2
    assert "pos.txt" in capsys.readouterr().err
    assert _cli(ours, "--pas", str(tmp_path / "good.npy")) == 2
    assert "--positions" in capsys.readouterr().err
    assert _cli(ours) == 2
    assert "--out" in capsys.readouterr().err


def test_read_pas_names_the_file(tmp_path):
    from rfmitsuba.eval.locate import read_pas

    with pytest.raises(DatasetError, match="does not exist"):
        read_pas(tmp_path / "none.npy")
    (tmp_path / "junk.npy").write_text("not an array")
    with pytest.raises(DatasetError, match="junk.npy"):
        read_pas(tmp_path / "junk.npy")
    np.save(tmp_path / "one.npy", np.ones((90, 360)))
    assert read_pas(tmp_path / "one.npy").shape == (1, 90, 360)


def test_open_two_stage_refuses_other_folders(tmp_path):
    from rfmitsuba.eval.locate import open_two_stage

    (tmp_path / "train").mkdir()
    with pytest.raises(RunError, match="another method's job"):
        open_two_stage(tmp_path)
    (tmp_path / "stage1.json").write_text("{}")
    with pytest.raises(RunError, match="Stage 2 has not finished"):
        open_two_stage(tmp_path)
