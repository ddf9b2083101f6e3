"""rfmitsuba.train.select: model = "auto" chooses the Stage-1 field by validation SSIM."""
from __future__ import annotations

import json

import pytest
from stage1_data import make_dataset
from stage1_data import tiny_cfg


def test_auto_trains_each_candidate_keeps_the_best_and_resumes(tmp_path):
    from rfmitsuba.data import nerf2
    from rfmitsuba.data.store import open_dataset
    from rfmitsuba.eval.run import evaluate_run
    from rfmitsuba.train.select import AUTO_KINDS, MEASURED_KINDS, trial_config
    from rfmitsuba.train.trainer import load_run, train

    folder = nerf2.write(open_dataset(make_dataset(tmp_path / "tx", num_antennas=30, task="tx")), tmp_path / "n")
    cfg = tiny_cfg(model='"auto"', iterations=200, **{"coherent_gaussians.scatterers": 4})
    assert trial_config(cfg, "splat").iterations == 50 and trial_config(cfg, "splat").model == "splat"
    from dataclasses import replace

    from rfmitsuba.train.select import TRIAL_MAX
    assert trial_config(replace(cfg, iterations=2000), "splat").iterations == 500  # a quarter
    assert trial_config(replace(cfg, iterations=6000), "splat").iterations == TRIAL_MAX == 750  # capped
    out = tmp_path / "run"
    s = train(folder, out, cfg=cfg, quiet=True)
    choice = json.loads((out / "select" / "choice.json").read_text())
    # synthetic spectra record no ray tracer: they vary by measurement, and the Gaussian-process field is tried too
    assert set(choice["trials"]) == {*AUTO_KINDS, *MEASURED_KINDS}
    best = max(choice["trials"], key=lambda k: choice["trials"][k]["best_val_ssim"])
    assert choice["chosen"] == best and s["model"] == best and s["steps"] == (0 if best in MEASURED_KINDS else 200)
    rcfg, _, renderer = load_run(out)
    assert rcfg.model == best and renderer.fields[0].kind == best
    assert evaluate_run(out)["model"]["n"] > 0
    # the same command again: nothing is trained, the choice stands
    stamp = {p: p.stat().st_mtime_ns for p in out.rglob("*.npz")}
    assert train(folder, out, cfg=cfg, quiet=True)["model"] == best
    assert all(p.stat().st_mtime_ns == t for p, t in stamp.items())


def test_auto_names_every_refusal(tmp_path, monkeypatch):
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train import select
    from rfmitsuba.train.trainer import Trainer

    data = TrainData.open(make_dataset(tmp_path / "ds", num_antennas=20))
    monkeypatch.setattr(select, "AUTO_KINDS", ("coherent",))  # needs a scene the synthetic data lacks
    monkeypatch.setattr(select, "MEASURED_KINDS", ())
    with pytest.raises(ConfigError, match="no candidate field can train.*coherent:.*needs the scene geometry"):
        select.select_model(tiny_cfg(model='"auto"'), data, tmp_path / "run", trainer=Trainer, quiet=True)


def test_a_candidate_that_diverges_is_left_out(tmp_path, monkeypatch):
    """A candidate whose trial raises RunError (a diverging loss) is recorded as refused; the other wins."""
    from rfmitsuba.core.errors import RunError
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train import select
    from rfmitsuba.train.trainer import Trainer

    class Diverging(Trainer):
        def run(self, **kw):
            if self.cfg.model == "coherent_gaussians":
                raise RunError("loss became nan at step 3")
            return super().run(**kw)

    data = TrainData.open(make_dataset(tmp_path / "ds", num_antennas=20))
    cfg = select.select_model(tiny_cfg(model='"auto"', iterations=40), data, tmp_path / "run", trainer=Diverging,
                              quiet=True)
    choice = json.loads((tmp_path / "run" / "select" / "choice.json").read_text())
    assert cfg.model == "splat" and "nan" in choice["refused"]["coherent_gaussians"]


def test_a_known_room_also_tries_more_paths_and_the_field_without_ray_casts(tmp_path):
    """Where the dataset names its room, the coherent Gaussian field is a candidate three times
    (ray casts, ray casts with more paths, windows alone); without a room, or with the casts
    turned off, once; with the orders already at PATHS_ORDERS, PATHS is not tried twice."""
    from types import SimpleNamespace

    from rfmitsuba.core import config as C
    from rfmitsuba.train import select
    from rfmitsuba.train.config import TrainConfig

    cfg = TrainConfig()
    known, blind = SimpleNamespace(scene_xml="room.xml"), SimpleNamespace(scene_xml=None)
    assert select.candidates(cfg, known) == ["coherent_gaussians", select.PATHS, select.WINDOWS, "splat"]
    assert select.candidates(cfg, blind) == list(select.AUTO_KINDS)
    given = C.override(cfg, ['scene="bedroom"'])                         # --set scene=... gives a folder its room
    assert select.WINDOWS in select.candidates(given, blind)
    off = C.override(cfg, ["coherent_gaussians.ray_visibility=false"])
    assert select.WINDOWS not in select.candidates(off, known) and select.PATHS not in select.candidates(off, known)
    p = select.candidate_config(cfg, select.PATHS)
    assert p.model == "coherent_gaussians" and p.coherent_gaussians.ray_visibility is True
    assert (p.coherent_gaussians.room_order, p.coherent_gaussians.furniture_order) == select.PATHS_ORDERS
    assert (cfg.coherent_gaussians.room_order, cfg.coherent_gaussians.furniture_order) != select.PATHS_ORDERS
    rich = C.override(cfg, ["coherent_gaussians.room_order=4", "coherent_gaussians.furniture_order=2"])
    assert select.candidates(rich, known) == ["coherent_gaussians", select.WINDOWS, "splat"]
    lower = C.override(cfg, ["coherent_gaussians.room_order=4", "coherent_gaussians.furniture_order=1"])
    q = select.candidate_config(lower, select.PATHS).coherent_gaussians
    assert (q.room_order, q.furniture_order) == (4, 2)                     # never fewer paths than asked
    w = select.candidate_config(cfg, select.WINDOWS)
    assert w.model == "coherent_gaussians" and w.coherent_gaussians.ray_visibility is False
    assert select.candidate_config(cfg, "splat").model == "splat"


def test_spectra_that_vary_by_measurement_also_try_the_gaussian_process_field():
    """Measured spectra, or a simulation with a measurement drift (TrainData.varies_by_measurement),
    add the Gaussian-process field to the candidates; a ray-traced simulation without one does not."""
    from types import SimpleNamespace

    from rfmitsuba.train import select
    from rfmitsuba.train.config import TrainConfig

    cfg = TrainConfig()
    measured = SimpleNamespace(scene_xml=None, varies_by_measurement=True)
    simulated = SimpleNamespace(scene_xml=None, varies_by_measurement=False)
    assert select.candidates(cfg, measured) == [*select.AUTO_KINDS, *select.MEASURED_KINDS]
    assert "gaussian_process" in select.MEASURED_KINDS
    assert select.candidates(cfg, simulated) == list(select.AUTO_KINDS)
