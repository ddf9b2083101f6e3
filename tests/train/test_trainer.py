"""Tests of rfmitsuba.train: configs, learning, resuming, run folders and bad input."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from stage1_data import make_dataset, tiny_cfg


@pytest.fixture(scope="module")
def tiny_ds(tmp_path_factory, variant):
    """60 positions (48 train, 12 test) rendered from a known 30-Gaussian field."""
    return make_dataset(tmp_path_factory.mktemp("tiny") / "ds", num_antennas=60)


def _rows(run):
    return [json.loads(ln) for ln in (run / "log.jsonl").read_text().splitlines()]


def test_config_round_trip_and_unknown_option():
    from rfmitsuba.core import config as C
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.train.config import TrainConfig, quick_config

    cfg = quick_config(tiny_cfg(seed=3))
    assert C.from_toml(TrainConfig, C.to_toml(cfg)) == cfg
    assert C.from_json(TrainConfig, C.to_json(cfg)) == cfg
    with pytest.raises(ConfigError, match="nope"):
        C.override(cfg, ["splat.nope=1"])
    with pytest.raises(ConfigError, match="downsample"):
        C.override(cfg, ["downsample=7"])
    with pytest.raises(ConfigError, match="unknown option"):
        C.from_toml(TrainConfig, "iterationz = 3")


def test_loss_decreases_and_run_folder_is_complete(tiny_ds, tmp_path):
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.models.splat import SplatField, read_ply
    from rfmitsuba.train.trainer import Trainer

    run = tmp_path / "run"
    s = Trainer(tiny_cfg(iterations=60), TrainData.open(tiny_ds), run, quiet=True).run()
    rows = _rows(run)
    first, last = rows[0]["loss"], np.mean([r["loss"] for r in rows[-2:]])
    assert last < 0.8 * first, (first, last)
    assert s["steps"] == 60 and s["num_gaussians"] > 0
    assert s["num_parameters"] == s["num_gaussians"] * 11 + s["network_parameters"]
    for f in ["config.toml", "run.json", "split.json", "final/field.npz", "final/gaussians.ply",
              "final/network.npz", "final/summary.json", "checkpoint/state.npz"]:
        assert (run / f).is_file(), f
    split = json.loads((run / "split.json").read_text())
    assert not set(split["test"]) & set(split["train"])
    assert set(split["val"]) <= set(split["train"]) and not set(split["val"]) & set(split["fit"])
    f = SplatField.load(run / "final" / "field.npz")
    assert len(read_ply(run / "final" / "gaussians.ply")["x"]) == f.num_gaussians == s["num_gaussians"]


def test_a_fields_penalty_is_added_to_the_loss(tiny_ds, tmp_path, monkeypatch):
    """``Field.penalty()`` (None by default) joins every step's loss: a constant 5 shows in the log."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.models.splat import SplatField
    from rfmitsuba.train.trainer import Trainer

    assert SplatField.penalty(None) is None
    monkeypatch.setattr(SplatField, "penalty", lambda self: B.Float([5.0]))
    run = tmp_path / "run"
    Trainer(tiny_cfg(iterations=10), TrainData.open(tiny_ds), run, quiet=True).run()
    losses = [r["loss"] for r in _rows(run) if "loss" in r]
    assert losses and min(losses) > 5.0 and max(losses) < 6.0


def test_killed_run_resumes_to_the_same_result(tiny_ds, tmp_path):
    """A run stopped after step 25 (last checkpoint: step 20) and started again ends where an
    uninterrupted run ends: same Gaussians (count and values within float tolerance), same log."""
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.trainer import Trainer

    data = TrainData.open(tiny_ds)
    cfg = tiny_cfg()
    a, b = tmp_path / "a", tmp_path / "b"
    Trainer(cfg, data, a, quiet=True).run()
    r = Trainer(cfg, data, b, quiet=True).run(stop_at=25)
    assert r["stopped"] == "stop_at"
    assert not (b / "final").exists()
    assert json.loads((b / "checkpoint" / "meta.json").read_text())["step"] == 20
    Trainer(cfg, data, b, quiet=True).run()
    with np.load(a / "final" / "field.npz") as za, np.load(b / "final" / "field.npz") as zb:
        assert za["means"].shape == zb["means"].shape
        for k in ["means", "log_scales", "rotations", "opacity_logits", "net.head", "net.gaussian"]:
            np.testing.assert_allclose(za[k], zb[k], rtol=1e-3, atol=1e-4, err_msg=k)
    ra, rb = _rows(a), _rows(b)
    assert [x["step"] for x in ra] == [x["step"] for x in rb]
    np.testing.assert_allclose([x["loss"] for x in ra], [x["loss"] for x in rb], rtol=1e-3)


def test_one_thread_makes_a_run_bit_reproducible(tiny_ds, tmp_path):
    """threads = 1: two runs of one configuration give bit-identical fields and losses, and the
    Dr.Jit thread count is restored afterwards; a negative count is refused by name."""
    import dataclasses

    import drjit as dr

    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.config import TrainConfig
    from rfmitsuba.train.trainer import Trainer

    data = TrainData.open(tiny_ds)
    cfg = dataclasses.replace(tiny_cfg(), threads=1)
    before = dr.thread_count()
    for name in ("a", "b"):
        Trainer(cfg, data, tmp_path / name, quiet=True).run()
        assert dr.thread_count() == before
    with np.load(tmp_path / "a" / "final" / "field.npz") as za, np.load(tmp_path / "b" / "final" / "field.npz") as zb:
        assert sorted(za.files) == sorted(zb.files)
        for k in za.files:
            np.testing.assert_array_equal(za[k], zb[k], err_msg=k)
    assert [x["loss"] for x in _rows(tmp_path / "a")] == [x["loss"] for x in _rows(tmp_path / "b")]
    with pytest.raises(ConfigError, match="threads"):
        TrainConfig(threads=-1)


def test_downsample_zero_takes_the_fields_advice_and_validation_is_at_full_resolution(tiny_ds, tmp_path):
    """``downsample = "auto"`` trains at the field kind's advice (the coherent Gaussian field at 45 x
    180, the others at 90 x 360); any ``d`` trains on (90/d) x (360/d) images but validates at 90 x
    360, so the logged validation SSIM is the metric's: the final field rendered at 90 x 360 at the
    validation positions scores it again."""
    from rfmitsuba.core.ssim import ssim_images
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.rf.bartlett_ref import normalize
    from rfmitsuba.train.config import training_downsample
    from rfmitsuba.train.trainer import Trainer, load_run

    assert training_downsample(tiny_cfg(downsample='"auto"', model="coherent_gaussians")) == 2
    assert training_downsample(tiny_cfg(downsample='"auto"', model="splat")) == 1
    assert training_downsample(tiny_cfg(downsample=3, model="coherent_gaussians")) == 3
    data = TrainData.open(tiny_ds)
    tr = Trainer(tiny_cfg(downsample='"auto"', model="coherent_gaussians"), data, tmp_path / "cg", quiet=True)
    assert (tr.h, tr.w) == (45, 180)

    run = tmp_path / "run"   # one check, at the last step, after the last density change
    s = Trainer(tiny_cfg(iterations=20, val_every=20, checkpoint_every=20, **{"density.start": 1000}), data, run,
                quiet=True).run()
    assert json.loads((run / "run.json").read_text())["image"] == [18, 72]
    _, data, fields = load_run(run)
    val = np.array(json.loads((run / "split.json").read_text())["val"])
    again = ssim_images(normalize(fields.render(data, val)), data.pas(val)).mean()
    assert s["val_ssim"] == pytest.approx(again, abs=1e-4)


def test_several_starts_keep_the_best_by_validation_and_resume(tiny_ds, tmp_path):
    """starts = 2: both copies of the initial field train start_steps(80) = 50 steps on their own
    batches, the one with the better validation SSIM goes on to step 80 (starts.json says which,
    the log's first row is its step 50); a run stopped at step 65 resumes from its step-60
    checkpoint without choosing again and ends bit-identical (one thread); starts outside 0..16
    are refused by name."""
    import dataclasses

    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.config import TrainConfig
    from rfmitsuba.train.trainer import Trainer, start_steps

    assert start_steps(80) == 50 and start_steps(6000) == 600 and start_steps(30000) == 1000
    assert start_steps(20) == 19
    data = TrainData.open(tiny_ds)
    cfg = dataclasses.replace(tiny_cfg(iterations=80), starts=2, threads=1)
    a, b = tmp_path / "a", tmp_path / "b"
    s = Trainer(cfg, data, a, quiet=True).run()
    st = json.loads((a / "starts.json").read_text())
    vals = [r["val_ssim"] for r in st["starts"]]
    assert st["steps"] == 50 and len(vals) == 2 and vals[0] != vals[1]
    assert st["chosen"] == int(np.argmax(vals))
    rows = _rows(a)
    assert rows[0]["step"] == 50 and rows[0]["start"] == st["chosen"] and rows[0]["val_ssim"] == max(vals)
    assert s["steps"] == 80 and s["train_time_s"] >= st["train_time_s"]
    assert Trainer(cfg, data, b, quiet=True).run(stop_at=65)["stopped"] == "stop_at"
    (b / "starts.json").write_text("{}")          # resuming does not choose again
    Trainer(cfg, data, b, quiet=True).run()
    assert (b / "starts.json").read_text() == "{}"
    with np.load(a / "final" / "field.npz") as za, np.load(b / "final" / "field.npz") as zb:
        for k in za.files:
            np.testing.assert_array_equal(za[k], zb[k], err_msg=k)
    for bad in (-1, 17):
        with pytest.raises(ConfigError, match="starts"):
            TrainConfig(starts=bad)


def test_epochs_lengthen_a_run_to_passes_over_the_fitting_positions(tiny_ds, tmp_path):
    """epochs = 3 over the 43 fitting positions at batch 4 trains ceil(3 * 43 / 4) = 33 steps
    where iterations asks for 20, and the learning rates reach their final values at step 33;
    -1 follows the field's advice (a splat field advises none); bad values are refused."""
    import dataclasses

    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.config import TrainConfig
    from rfmitsuba.train import resolve
    from rfmitsuba.train.trainer import Trainer

    data = TrainData.open(tiny_ds)
    cfg = dataclasses.replace(tiny_cfg(iterations=20), epochs=3.0)
    t = Trainer(cfg, data, tmp_path / "a", quiet=True)
    s = t.run()
    fit = json.loads((tmp_path / "a" / "split.json").read_text())["fit"]
    want = -(-3 * len(fit) // 4)
    assert len(fit) == 43 and s["steps"] == s["iterations"] == want == 33
    lr_end, lr_mid = t._lrs(want - 1), t._lrs(want // 2)
    t.iterations = 20
    assert t._lrs(19) == lr_end and t._lrs(want // 2) != lr_mid     # the schedule spans the longer run
    assert Trainer(tiny_cfg(iterations=20), data, tmp_path / "b", quiet=True).run()["steps"] == 20   # -1: splat, none
    assert resolve.iterations(cfg, 43, 0.0).value == 20
    assert resolve.iterations(cfg, 43, 1.0).value == 20                                      # 11 < 20
    for bad in (-2.0, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="epochs"):
            TrainConfig(epochs=bad)


def test_learning_rate_schedules_decay_to_their_final_values(tiny_ds, tmp_path):
    """A group with a ``*_final`` rate decays exponentially to it at the last step (half-way:
    the geometric mean); the rotations' rate stays constant."""
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.trainer import Trainer

    data = TrainData.open(tiny_ds)
    cfg = tiny_cfg(iterations=101)
    t = Trainer(cfg, data, tmp_path / "a", quiet=True)
    assert t._lrs(0)["rotations"] == t._lrs(100)["rotations"] == cfg.optim.lr_rotations
    assert t._lrs(100)["means"] == pytest.approx(cfg.optim.lr_means_final)
    assert t._lrs(50)["means"] == pytest.approx((cfg.optim.lr_means * cfg.optim.lr_means_final) ** 0.5)


def _scripted_validation(monkeypatch, table: dict):
    """Make Trainer.validate return ``table[step]`` (the step just trained), so a test decides
    where a run's validation SSIM dips; the training itself is untouched."""
    from rfmitsuba.train.trainer import Trainer

    step_of = Trainer._step

    def _step(self, *a, **kw):
        out = step_of(self, *a, **kw)
        self._scripted_step = a[4] + 1 if len(a) > 4 else kw.get("step", 0) + 1
        return out

    monkeypatch.setattr(Trainer, "_step", _step)
    monkeypatch.setattr(Trainer, "validate", lambda self, field, val, gt: table[self._scripted_step])


def test_a_collapse_on_the_last_check_reverts_to_the_tails_best(tiny_ds, tmp_path, monkeypatch, one_thread):
    """revert_drop: the last check (step 40) 0.4 below the tail's best (step 30) keeps the field
    of step 30, bit for bit the state a run stopped at step 30 checkpointed; resumed from step
    30 it ends the same; a drop within revert_drop, or revert_drop = 0, keeps the last state."""
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.config import TrainConfig
    from rfmitsuba.train.trainer import Trainer

    data = TrainData.open(tiny_ds)
    cfg = tiny_cfg(threads=1, **{"density.start": 1000})   # no density events: one structure throughout
    _scripted_validation(monkeypatch, {10: 0.8, 20: 0.85, 30: 0.9, 40: 0.5})
    s = Trainer(cfg, data, tmp_path / "a", quiet=True).run()
    assert s["revert"] == {"from_step": 40, "from_val_ssim": 0.5, "to_step": 30, "to_val_ssim": 0.9,
                           "reverted": True}
    assert s["val_ssim"] == 0.9 and s["steps"] == 40
    Trainer(cfg, data, tmp_path / "b", quiet=True).run(stop_at=30)
    with np.load(tmp_path / "a" / "final" / "field.npz") as za, \
            np.load(tmp_path / "b" / "checkpoint" / "state.npz") as zb:
        for k in ["means", "log_scales", "opacity_logits", "net.head"]:
            np.testing.assert_array_equal(za[k], zb["field/" + k], err_msg=k)
    Trainer(cfg, data, tmp_path / "b", quiet=True).run()          # resumed: the tail's best came along
    with np.load(tmp_path / "a" / "final" / "field.npz") as za, np.load(tmp_path / "b" / "final" / "field.npz") as zb:
        np.testing.assert_array_equal(za["means"], zb["means"])
    _scripted_validation(monkeypatch, {10: 0.8, 20: 0.85, 30: 0.9, 40: 0.895})
    assert Trainer(cfg, data, tmp_path / "c", quiet=True).run()["revert"] is None
    _scripted_validation(monkeypatch, {10: 0.8, 20: 0.85, 30: 0.9, 40: 0.5})
    off = tiny_cfg(threads=1, revert_drop=0.0, **{"density.start": 1000})
    s = Trainer(off, data, tmp_path / "d", quiet=True).run()
    assert s["revert"] is None and s["val_ssim"] == 0.5
    for bad in (-0.1, 2.0, float("nan")):
        with pytest.raises(ConfigError, match="revert_drop"):
            TrainConfig(revert_drop=bad)


def test_run_folders_written_with_removed_options_still_open(tiny_ds, tmp_path):
    """A run whose config.toml holds removed options at the values the code now behaves as
    (``members = 1``, ``val_positions = "random"``) opens, evaluates and resumes as before; one
    that used them otherwise (an ensemble, ``members = 2``) is refused naming the option, an
    ensemble's folder names the member run to open instead, and a user's override of a removed
    option is told it was removed."""
    from rfmitsuba.core import config as C
    from rfmitsuba.core.errors import ConfigError, RunError
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.config import TrainConfig
    from rfmitsuba.train.trainer import Trainer, load_run

    data = TrainData.open(tiny_ds)
    cfg = tiny_cfg(iterations=10)
    run = tmp_path / "run"
    s = Trainer(cfg, data, run, quiet=True).run()
    toml = run / "config.toml"
    toml.write_text('members = 1\nval_positions = "random"\n' + toml.read_text())
    assert load_run(run)[0] == cfg
    assert Trainer(cfg, data, run, quiet=True).run() == s            # the resume check sees the same config
    toml.write_text(toml.read_text().replace("members = 1", "members = 2"))
    with pytest.raises(ConfigError, match="TrainConfig.members = 2: this saved file used an option that was removed"):
        load_run(run)
    toml.write_text(toml.read_text().replace("members = 2", "members = 1"))
    (run / "final" / "members.json").write_text("{}")
    with pytest.raises(RunError, match="ensemble .* open .*members/0"):
        load_run(run)
    with pytest.raises(ConfigError, match="members: this option was removed"):
        C.override(cfg, ["members=2"])
    # a renamed section: the splat field's options were [field]
    (run / "final" / "members.json").unlink()
    toml.write_text(toml.read_text().replace("[splat]", "[field]").replace("[splat.", "[field."))
    assert "[field]" in toml.read_text() and load_run(run)[0] == cfg
    mine = tmp_path / "mine.toml"     # the same file as a user's configuration, without the removed options
    mine.write_text(toml.read_text().replace('members = 1\nval_positions = "random"\n', ""))
    with pytest.raises(ConfigError, match="TrainConfig.field: this option is called 'splat' now"):
        C.load(TrainConfig, mine)
    with pytest.raises(ConfigError, match="the section 'field' is called 'splat' now"):
        C.override(cfg, ["field.num_gaussians=10"])


def test_run_folders_from_before_the_last_options_were_removed_still_open(tiny_ds, tmp_path):
    """A run saved with the options removed since (one jittered copy, a decay of the rotations'
    rate, density control's stop step, the coherent Gaussian field's furniture planes, the
    network's encoding and hash-grid settings) at their old defaults opens as the same
    configuration; a saved hash-grid network is refused naming the option, and a user's override
    of any of them is told it was removed."""
    from rfmitsuba.core import config as C
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.trainer import Trainer, load_run

    data = TrainData.open(tiny_ds)
    cfg = tiny_cfg(iterations=10)
    run = tmp_path / "run"
    Trainer(cfg, data, run, quiet=True).run()
    toml = run / "config.toml"
    old = {"": "jitter_views = 1\n", "[optim]\n": "lr_rotations_final = 0.0\n", "[density]\n": "stop = 100000\n",
           "[coherent_gaussians]\n": 'furniture_planes = "faces"\n',
           "[splat.net]\n": 'encoding = "sin"\nhash_levels = 8\nhash_features = 2\nhash_log2_size = 14\n'
                            'hash_base_resolution = 4\nhash_per_level_scale = 1.6\n'}
    text = toml.read_text()
    for section, lines in old.items():
        assert section in text
        text = lines + text if not section else text.replace(section, section + lines, 1)
    toml.write_text(text)
    assert load_run(run)[0] == cfg
    toml.write_text(text.replace('encoding = "sin"', 'encoding = "hashgrid"'))
    with pytest.raises(ConfigError, match="encoding = 'hashgrid': this saved file used an option that was removed"):
        load_run(run)
    for option in ("jitter_views=2", "optim.lr_rotations_final=1e-5", "density.stop=500",
                   'coherent_gaussians.furniture_planes="box"', "splat.net.hash_levels=4"):
        with pytest.raises(ConfigError, match="this option was removed"):
            C.override(cfg, [option])


def test_run_folder_of_another_config_is_refused(tiny_ds, tmp_path):
    from rfmitsuba.core.errors import RunError
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.trainer import Trainer

    data = TrainData.open(tiny_ds)
    run = tmp_path / "run"
    Trainer(tiny_cfg(iterations=10), data, run, quiet=True).run()
    before = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    with pytest.raises(RunError, match="splat.num_gaussians"):
        Trainer(tiny_cfg(iterations=10, **{"splat.num_gaussians": 99}), data, run, quiet=True)
    after = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    assert before == after
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(RunError, match="not a run folder"):
        Trainer(tiny_cfg(), data, other, quiet=True)
    assert (other / "notes.txt").read_text() == "mine"


def test_bad_datasets_are_clear_errors(tiny_ds, tmp_path):
    from rfmitsuba.core.errors import DatasetError
    from rfmitsuba.data.views import TrainData

    with pytest.raises(DatasetError, match="does not exist"):
        TrainData.open(tmp_path / "missing")
    d1 = tmp_path / "no_pos"
    shutil.copytree(tiny_ds, d1)
    (d1 / "antenna_pos.npy").unlink()
    with pytest.raises(DatasetError, match="antenna_pos"):
        TrainData.open(d1)
    d2 = tmp_path / "bad_shape"
    shutil.copytree(tiny_ds, d2)
    np.save(d2 / "antenna_pos.npy", np.zeros((7, 3), np.float32))
    with pytest.raises(DatasetError, match="shape"):
        TrainData.open(d2)


def test_nan_in_pas_names_the_position(tmp_path, variant):
    from rfmitsuba.core.errors import DatasetError
    from rfmitsuba.data.store import write_dataset
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.trainer import Trainer

    pas = np.random.default_rng(0).random((1, 10, 90, 360)).astype(np.float32)
    pas[0, 3, 5, 5] = np.nan
    ap = np.random.default_rng(1).uniform(0.5, 2.5, (10, 3))
    write_dataset(tmp_path / "ds", pas=pas, antenna_pos=ap, person_pos=np.full((1, 3), np.nan), meta={"task": "rx"})
    data = TrainData.open(tmp_path / "ds")
    with pytest.raises(DatasetError, match="antenna position 3"):
        data.pas(np.arange(10))
    with pytest.raises(DatasetError, match="NaN"):
        Trainer(tiny_cfg(**{"val_fraction": 0.0}), data, tmp_path / "run", quiet=True).run()


def test_cli_train_and_unknown_option(tiny_ds, tmp_path, capsys):
    from rfmitsuba.cli import main

    run = tmp_path / "run"
    cfg = tmp_path / "c.toml"
    from rfmitsuba.core import config as C

    C.save(tiny_cfg(iterations=10), cfg)
    assert main(["train", str(tiny_ds), "--out", str(run), "--config", str(cfg), "--quiet"]) == 0
    assert "10 steps" in capsys.readouterr().out
    assert main(["train", str(tiny_ds), "--out", str(tmp_path / "r2"), "--config", str(cfg),
                 "--set", "splat.colour=1"]) == 2
    assert "colour" in capsys.readouterr().err
    assert not (tmp_path / "r2").exists()


def test_moving_tx_task_trains(tmp_path, variant):
    """Moving TX: the view is the fixed array, the network input the transmitter position."""
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.trainer import Trainer

    ds = make_dataset(tmp_path / "tx", num_antennas=30, task="tx")
    data = TrainData.open(ds)
    assert data.task == "tx" and np.allclose(data.view_pos, data.view_pos[0])
    s = Trainer(tiny_cfg(iterations=10), data, tmp_path / "run", quiet=True).run()
    assert s["task"] == "tx" and s["steps"] == 10


def test_nerf2_folder_trains(tiny_ds, tmp_path):
    """A NeRF2 spectrum folder (written from the tiny moving-TX dataset) trains and evaluates;
    the gateway orientation reaches the renderer as rx_to_world; no scene -> random init with a
    warning, whatever splat.init says; --split block holds out the slab of largest x."""
    from rfmitsuba.data import nerf2
    from rfmitsuba.data.store import open_dataset
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.eval.run import evaluate_run
    from rfmitsuba.train.trainer import Trainer

    ds = make_dataset(tmp_path / "tx", num_antennas=30, task="tx")
    folder = nerf2.write(open_dataset(ds), tmp_path / "nerf2")
    data = TrainData.open(folder)
    assert data.task == "tx" and data.scene_xml is None
    np.testing.assert_allclose(data.rx_to_world, np.eye(3), atol=1e-12)
    with pytest.warns(UserWarning, match="names no scene"):
        Trainer(tiny_cfg(iterations=10, **{"splat.init": '"mesh"'}), data, tmp_path / "run", quiet=True).run()
    m = evaluate_run(tmp_path / "run")
    assert m["test_positions"] == len(data.test) and m["split"] == "dataset"
    # the spatial-block split: the test positions are the slab of the largest x
    Trainer(tiny_cfg(iterations=4, split='"block"'), data, tmp_path / "block", quiet=True).run()
    sp = json.loads((tmp_path / "block" / "split.json").read_text())
    x = data.antenna_pos[:, 0]
    assert len(sp["test"]) == 6 and x[sp["test"]].min() > x[sp["train"]].max()
    assert evaluate_run(tmp_path / "block")["split"] == "block"
    # validation: seeded positions among the training ones, so the training block's outer tags
    # stay in the fit
    train = np.asarray(sp["train"])
    for seed in range(3):
        c = tiny_cfg(iterations=4, split='"block"', val_fraction=0.2, seed=seed)
        val = np.asarray(Trainer(c, data, tmp_path / f"v{seed}", quiet=True)._make_split(
            np.random.default_rng(seed))["val"])
        assert len(val) == 5 and np.isin(val, train).all()


def test_a_run_that_fails_before_its_first_checkpoint_leaves_no_folder(tiny_ds, tmp_path):
    """The coherent field refuses a dataset without a scene: the run folder it would have made is
    gone, so the corrected retry into the same --out starts clean."""
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.data import nerf2
    from rfmitsuba.data.store import open_dataset
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.trainer import Trainer

    folder = nerf2.write(open_dataset(make_dataset(tmp_path / "tx", num_antennas=30, task="tx")), tmp_path / "n")
    data = TrainData.open(folder)
    out = tmp_path / "run"
    with pytest.raises(ConfigError, match="names no"):
        Trainer(tiny_cfg(iterations=5, model='"coherent"'), data, out, quiet=True).run()
    assert not out.exists()
    assert Trainer(tiny_cfg(iterations=5), data, out, quiet=True).run()["steps"] == 5
    # an existing folder is never removed by a failure
    out2 = tmp_path / "kept"
    out2.mkdir()
    with pytest.raises(ConfigError):
        Trainer(tiny_cfg(iterations=5, model='"coherent"'), data, out2, quiet=True).run()
    assert out2.is_dir()


def test_config_model_is_a_registered_stage1_kind():
    from rfmitsuba.core.errors import ConfigError

    with pytest.raises(ConfigError, match="unknown field kind 'nerf'.*known:.*splat"):
        tiny_cfg(model='"nerf"')
    with pytest.raises(ConfigError, match="Stage-2 person field"):
        tiny_cfg(model='"splat_person"')
    with pytest.raises(ConfigError, match="split"):
        tiny_cfg(split='"slab"')


def test_stage2_pattern_frozen_background_plus_trainable_set(tiny_ds, tmp_path):
    """What Stage 2 does: load and freeze a trained background, train a second set with an extra
    network input rendered in the same call; the background does not change."""
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.models.splat import SplatField
    from rfmitsuba.train.trainer import Trainer

    data = TrainData.open(tiny_ds)
    Trainer(tiny_cfg(iterations=10), data, tmp_path / "bg", quiet=True).run()
    bg = SplatField.load(tmp_path / "bg" / "final" / "field.npz")
    bg.freeze()
    before = bg.state_dict()
    person = np.array([1.0, 2.0, 0.0])
    extra = lambda idx: np.tile(person / 4.0, (len(idx), 1))  # noqa: E731
    tr = Trainer(tiny_cfg(iterations=10, **{"splat.num_gaussians": 40}), data, tmp_path / "h", frozen=[bg],
                 extra=extra, extra_inputs=3, name="person", quiet=True)
    s = tr.run()
    assert s["num_gaussians"] == tr.field.num_gaussians and tr.field.extra_inputs == 3
    after = bg.state_dict()
    for k in ["means", "opacity_logits", "net.head"]:
        np.testing.assert_array_equal(before[k], after[k])
    img = tr.render(tr.field, data.train[:2])
    assert img.shape == (2, 18, 72)


def test_shipped_configs_load():
    """Every TOML under configs/ is a valid TrainConfig (the README points users at them)."""
    from pathlib import Path

    from rfmitsuba.core import config
    from rfmitsuba.train.config import TrainConfig

    files = sorted((Path(__file__).resolve().parents[2] / "configs").glob("*.toml"))
    assert files
    for f in files:
        cfg = config.load(TrainConfig, f)
        assert config.from_toml(TrainConfig, config.to_toml(cfg)) == cfg


# --------------------------------------------------------------------------- the coherent model

def coherent_cfg(**over):
    from rfmitsuba.core import config as C
    from rfmitsuba.train.config import TrainConfig

    sets = ["model=\"coherent\"", "iterations=30", "batch_views=4", "val_every=10", "checkpoint_every=10",
            "log_every=5", "coherent.room_order=2", "coherent.furniture_order=1"]
    return C.override(TrainConfig(), sets + [f"{k}={v}" for k, v in over.items()])


@pytest.fixture(scope="module")
def empty_bedroom(tmp_path_factory, variant):
    """Sionna bedroom, moving RX, 300 positions (240 train, 60 test), empty room, 2e4 ray samples.
    Same as ``rfmitsuba generate bedroom --task rx --positions 300 --person-positions 0 --samples 20000``."""
    from rfmitsuba.sim import generate as gen
    from rfmitsuba.sim.simulate import SolverConfig

    cfg = gen.GenerateConfig(scene="bedroom", task="rx", positions=300, person_positions=0,
                                 solver=SolverConfig(samples_per_src=20_000))
    return gen.generate(tmp_path_factory.mktemp("empty_bedroom") / "ds", cfg, quiet=True).path


def test_coherent_model_learns_the_bedroom_and_beats_nearest_neighbour(empty_bedroom, tmp_path, one_thread):
    """The coherent image-source model on Sionna data (bedroom, 240 training positions): after 400
    steps (8 views each) its held-out SSIM is above the nearest-neighbour floor, and the run folder
    has the field, the sources as PLY and a summary.

    Measured on one Dr.Jit thread (this test, deterministic: on two threads the sums run in no
    fixed order and runs differ by up to 0.03, which this test's margin is): model 0.753 / nearest
    neighbour 0.696 / mean image 0.537 mean SSIM, the settings of ``rfmitsuba train DS --set
    model=coherent --set iterations=400 --set batch_views=8 --set coherent.room_order=2 --set
    coherent.furniture_order=1`` on the fixture's dataset. (With 80 training positions the model
    does not beat nearest neighbour: it has more parameters than 80 PAS constrain.)"""
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.eval.run import evaluate_run
    from rfmitsuba.models.splat import read_ply
    from rfmitsuba.train.trainer import Trainer

    data = TrainData.open(empty_bedroom)
    s = Trainer(coherent_cfg(iterations=400, batch_views=8, val_every=200, checkpoint_every=200), data,
                tmp_path / "run", quiet=True).run()
    assert s["model"] == "coherent" and s["steps"] == 400 and s["num_gaussians"] > 25
    ply = read_ply(tmp_path / "run" / "final" / "sources.ply")
    assert len(ply["x"]) == s["num_gaussians"]
    m = evaluate_run(tmp_path / "run", quiet=True)
    assert m["model"]["mean"] > m["nearest_neighbour"]["mean"] + 0.03, m


@pytest.fixture
def one_thread():
    """Dr.Jit on one thread: gradient scatter-adds then sum in a fixed order, so two runs of the same
    training agree to the last bit (with several threads they differ by about 1e-3 after 30 steps)."""
    import drjit as dr

    old = dr.thread_count()
    dr.set_thread_count(1)
    yield
    dr.set_thread_count(old)


def test_coherent_killed_run_resumes_to_the_same_result(quick_dataset, tmp_path, one_thread):
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.trainer import Trainer

    data = TrainData.open(quick_dataset.path)
    cfg = coherent_cfg()
    a, b = tmp_path / "a", tmp_path / "b"
    Trainer(cfg, data, a, quiet=True).run()
    assert Trainer(cfg, data, b, quiet=True).run(stop_at=15)["stopped"] == "stop_at"
    Trainer(cfg, data, b, quiet=True).run()
    with np.load(a / "final" / "field.npz") as za, np.load(b / "final" / "field.npz") as zb:
        for k in ["amp", "embed", "net.gain"]:
            np.testing.assert_allclose(za[k], zb[k], rtol=1e-4, atol=1e-5, err_msg=k)


def test_coherent_needs_a_scene_and_takes_one_for_a_nerf2_folder(quick_dataset, tmp_path):
    """A NeRF2 folder names no scene: the coherent model says so, and trains with --set scene=..."""
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.data import nerf2
    from rfmitsuba.data.store import open_dataset
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.train.trainer import Trainer

    folder = nerf2.write(open_dataset(quick_dataset.path), tmp_path / "nerf2")
    data = TrainData.open(folder)
    with pytest.raises(ConfigError, match="names no scene"):
        Trainer(coherent_cfg(iterations=2), data, tmp_path / "r0", quiet=True).run()
    s = Trainer(coherent_cfg(iterations=4, scene='"bedroom"'), data, tmp_path / "r1", quiet=True).run()
    assert s["steps"] == 4


def test_a_closed_form_field_is_conditioned_once_validated_and_evaluated(tmp_path):
    """model = "gaussian_process" on a folder as published (no rfmitsuba.json): no gradient steps,
    validation on the held-out training positions, a run that load_run and evaluate_run read, and
    the same command again changes nothing."""
    from rfmitsuba.core.ssim import ssim_images
    from rfmitsuba.data import nerf2
    from rfmitsuba.data.store import open_dataset
    from rfmitsuba.data.views import TrainData
    from rfmitsuba.eval.run import evaluate_run
    from rfmitsuba.models.gaussian_process import GaussianProcessField
    from rfmitsuba.rf.bartlett_ref import normalize as minmax
    from rfmitsuba.train.trainer import load_run, train

    folder = nerf2.write(open_dataset(make_dataset(tmp_path / "tx", num_antennas=40, task="tx")), tmp_path / "n")
    (folder / nerf2.EXTRA).unlink()
    assert TrainData.open(folder).measured
    out = tmp_path / "run"
    s = train(folder, out, cfg=tiny_cfg(model='"gaussian_process"'), quiet=True)
    assert s["stopped_by"] == "closed_form" and s["steps"] == 0 and 0 < s["val_ssim"] <= 1
    assert set(s["init"]["hyperparameters"]) >= {"length_scales_m", "nugget", "signal_variance"}
    rows = _rows(out)
    assert len(rows) == 1 and rows[0]["val_ssim"] == s["val_ssim"]
    cfg, data, renderer = load_run(out)
    assert renderer.fields[0].kind == "gaussian_process" and renderer.num_primitives == s["num_gaussians"]
    ev = evaluate_run(out)
    assert ev["model"]["n"] == len(data.test) and 0 < ev["model"]["mean"] <= 1
    # validated conditioned on the fitting positions alone, then conditioned on every training
    # position: the interpolating field draws the validation spectra it did not see at validation
    split = json.loads((out / "split.json").read_text())
    assert split["val"] and s["conditioned_on"] == sorted(split["train"]) == sorted(split["fit"] + split["val"])
    assert renderer.num_primitives == len(split["train"])
    fit, val = (np.asarray(split[k], np.int64) for k in ("fit", "val"))
    fit_only = GaussianProcessField()
    fit_only.condition(data.antenna_pos[fit], data.pas(fit))
    unseen = ssim_images(minmax(fit_only.predict(data.antenna_pos[val])), data.pas(val))
    drawn = ssim_images(minmax(renderer.fields[0].predict(data.antenna_pos[val])), data.pas(val))
    assert s["val_ssim"] == pytest.approx(unseen.mean(), abs=1e-4)
    assert drawn.min() > 0.9999 and drawn.mean() > unseen.mean()
    stamp = (out / "final" / "field.npz").stat().st_mtime_ns
    assert train(folder, out, cfg=tiny_cfg(model='"gaussian_process"'), quiet=True)["val_ssim"] == s["val_ssim"]
    assert (out / "final" / "field.npz").stat().st_mtime_ns == stamp
