"""rfmitsuba.train.resolve: every "auto" decided in one place; a run records the decisions in
resolved.toml, and ``train --dry-run`` prints them without training."""
from __future__ import annotations

import tomllib

import pytest
from stage1_data import make_dataset, tiny_cfg


@pytest.fixture(scope="module")
def tiny_ds(tmp_path_factory, variant):
    return make_dataset(tmp_path_factory.mktemp("resolve") / "ds", num_antennas=40, task="tx")


def test_a_run_records_what_it_decided_and_uses_it(tiny_ds, tmp_path):
    """A run of the default "auto" options writes resolved.toml: the block size, the passes, the
    steps, the starts and the jitter, each with a value and a reason; the steps it trained are
    the decided ones; an option set in the configuration is recorded as set."""
    import json

    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.trainer import Trainer

    cfg = tiny_cfg(iterations=12, epochs=4.0)   # 4 passes over the fitting positions at 4 views: more than 12
    s = Trainer(cfg, TrainData.open(tiny_ds), tmp_path / "run", quiet=True).run()
    got = tomllib.loads((tmp_path / "run" / "resolved.toml").read_text())
    assert {"downsample", "epochs", "iterations", "starts", "jitter"} <= set(got)
    assert all(isinstance(v["reason"], str) and v["reason"] for v in got.values())
    assert got["downsample"] == {"value": 5, "reason": "set in the configuration"}
    assert got["epochs"] == {"value": 4.0, "reason": "set in the configuration"}
    n_fit = len(json.loads((tmp_path / "run" / "split.json").read_text())["fit"])
    assert got["iterations"]["value"] == -(-4 * n_fit // 4) == s["steps"] > 12
    assert got["starts"]["value"] == 1 and got["jitter"]["value"] == 0.0


def test_the_coherent_gaussian_field_names_its_choices(tiny_ds):
    """The coherent Gaussian field's "auto" options are decided where it is built and listed with
    a reason each: simulated amplitude data, no room named: the amplitude read-out, the plane
    wavefront, no coupling, the data scan, the default grid."""
    from rfmitsuba.core import config as C
    from rfmitsuba.train import resolve
    from rfmitsuba.train.trainer import dry_run

    cfg = C.override(tiny_cfg(model='"coherent_gaussians"', downsample='"auto"'),
                     ["coherent_gaussians.scatterers=4"])
    text = dry_run(tiny_ds, cfg=cfg)
    got = tomllib.loads(text)
    assert got["downsample"]["value"] == 2
    assert got["coherent_gaussians.readout"]["value"] == "amplitude"
    assert got["coherent_gaussians.wavefront"]["value"] == "plane"
    assert got["coherent_gaussians.coupling"]["value"] is False
    assert got["coherent_gaussians.vis_grid"]["value"] == [4, 4, 2]
    init = got["coherent_gaussians.init"]
    assert init["value"] in ("room", "data") and init["reason"]
    with pytest.raises(KeyError):
        resolve.value([], "jitter")


def test_dry_run_trains_and_writes_nothing(tiny_ds, tmp_path, capsys):
    """``rfmitsuba train --dry-run`` with model "auto" names the trials, gives each candidate's
    decisions, and leaves no run folder behind."""
    from rfmitsuba.cli import main

    out = tmp_path / "run"
    assert main(["train", str(tiny_ds), "--out", str(out), "--dry-run", "--set", "iterations=40",
                 "--set", "coherent_gaussians.scatterers=4", "--quiet"]) == 0
    text = capsys.readouterr().out
    # the synthetic spectra record no ray tracer: the Gaussian-process field is a candidate too
    assert 'model = "auto": trials of coherent_gaussians, splat, gaussian_process at 50 steps each' in text
    assert "# if the trials choose coherent_gaussians:" in text and "# if the trials choose splat:" in text
    assert not out.exists()
