"""rfmitsuba.models.coherent_gaussians.build: the Stage-1 initial field from a dataset
(:func:`initial_field`, through ``CoherentGaussianField.for_training``).

A known room keeps only the images seen in training; an unknown room gets the default visibility
grid over the training positions; the line-of-sight frame fit reports a stated frame that is far
off; the calibration search starts the calibration at the fitted offsets (training from a NeRF2
folder without a scene)."""
from __future__ import annotations

import numpy as np
import pytest
from coherent_gaussians_cases import _stub_training_data


#: every test on one Dr.Jit thread (the ``one_thread`` fixture of tests/conftest.py)
pytestmark = pytest.mark.usefixtures("one_thread")


def test_known_room_keeps_only_images_seen_in_training():
    """for_training on a known room: the images whose path exists at no training position are
    left out (parsimony), the direct path always stays, and every kept image is seen somewhere."""
    from rfmitsuba.core import config as C
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianField
    from rfmitsuba.rf.images import scene_image_maps
    from rfmitsuba.scenes import path as scene_path
    from rfmitsuba.sim.geometry import RoomGeometry
    from rfmitsuba.train.config import TrainConfig

    xml = scene_path("bedroom")
    data, q, y = _stub_training_data(12, seed=0)
    cfg = C.override(TrainConfig(), ['model="coherent_gaussians"', "coherent_gaussians.room_scatterers=0",
                                     "coherent_gaussians.room_order=1"])
    f = CoherentGaussianField.for_training(cfg, data, scene_xml=xml)
    every = scene_image_maps(RoomGeometry.from_xml(xml), room_order=1, furniture_order=1, distinct_paths=True,
                             furniture_planes="faces")
    ex, _, _ = f.visibility(q, y)
    assert 1 < f.num_images < len(every) and f.order[0] == 0
    assert ex[:, 1:].any(0).all()
    # a known room gets the default visibility grid over the training positions' box (5% padding)
    assert f.cfg.vis_grid == (4, 4, 2) and f.grid_cells == 32 and "vis_grid_box" not in f.trainable()
    pad = 0.05 * (q.max(0) - q.min(0)) + 1e-3
    np.testing.assert_allclose(f.params["vis_grid_box"].numpy(), np.r_[q.min(0) - pad, q.max(0) + pad], rtol=1e-6)
    assert len(f.params["vis_grid"].numpy()) == 32 * f.num_primitives


def test_unknown_room_gets_the_default_visibility_grid():
    """for_training from a data scan (no room): the same default grid as a known room, over the
    training positions' box; (0, 0, 0) in the config turns it off."""
    from rfmitsuba.core import config as C
    from rfmitsuba.models.coherent_gaussians import DEFAULT_VIS_GRID, CoherentGaussianField
    from rfmitsuba.train.config import TrainConfig

    data, q, _ = _stub_training_data(10, seed=1)
    small = ['model="coherent_gaussians"', "coherent_gaussians.images=2", "coherent_gaussians.scatterers=4"]
    f = CoherentGaussianField.for_training(C.override(TrainConfig(), small), data, scene_xml=None)
    assert f.cfg.vis_grid == DEFAULT_VIS_GRID == (4, 4, 2) and f.grid_cells == 32
    pad = 0.05 * (q.max(0) - q.min(0)) + 1e-3
    np.testing.assert_allclose(f.params["vis_grid_box"].numpy(), np.r_[q.min(0) - pad, q.max(0) + pad], rtol=1e-6)
    off = CoherentGaussianField.for_training(C.override(TrainConfig(), small + ["coherent_gaussians.vis_grid=[0,0,0]"]),
                                             data, scene_xml=None)
    assert off.grid_cells == 0 and "vis_grid" not in off.parameters()


def test_frame_search_reports_a_stated_frame_that_is_far_off():
    """A measured folder whose stated gateway frame is 30 degrees off: by default ("auto" =
    "report" for a measured folder) the line-of-sight fit is reported in the run summary with the
    angle it found, a warning names the gateway orientation, and the field starts from the stated
    frame (pose zero); with the search off nothing is fitted."""
    import warnings
    from types import SimpleNamespace

    from rfmitsuba.core import config as C
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField
    from rfmitsuba.rf.frame_fit import rotation_matrix
    from rfmitsuba.train.config import TrainConfig

    from los_data import F as F920, los_spectra

    pas, x, y = los_spectra(true_to_world=np.eye(3), n=24)
    stated = rotation_matrix(np.radians(30) * np.array([0.6, 0.7, 0.39]) / np.linalg.norm([0.6, 0.7, 0.39]))
    data = SimpleNamespace(path="stub", train=np.arange(len(x)), rx_to_world=stated, frequency_hz=F920, measured=True,
                           readout="phase_only", task="tx", positions=lambda idx: (x[idx], y[idx], y[idx]),
                           pas=lambda idx, d=1: pas[idx] if d == 2 else None)
    base = ['model="coherent_gaussians"', "coherent_gaussians.images=0", "coherent_gaussians.scatterers=0",
            'coherent_gaussians.calibration_search="off"']
    for mode in ("auto", "off"):
        cfg = C.override(TrainConfig(), base + [f'coherent_gaussians.frame_search="{mode}"'])
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            f = CoherentGaussianField.for_training(cfg, data, scene_xml=None)
        assert not np.asarray(f.params["pose"].numpy()).any()
        if mode == "auto":
            rep = f.init_report["frame_fit"]
            assert 25 < rep["angle_deg"] < 35 and rep["score"] - rep["stated_score"] > 0.05
            assert any("gateway orientation" in str(w.message) for w in caught)
        else:
            assert f.init_report == {} and not any("gateway" in str(w.message) for w in caught)
    with pytest.raises(ConfigError, match="frame_search"):
        CoherentGaussianConfig(frame_search="on")


def test_calibration_search_starts_the_calibration_at_the_fitted_offsets():
    """Phase-only spectra (a NeRF2 folder) of an array whose elements carry offsets anywhere in
    +-180 degrees: by default ("auto") the initial field's line of sight draws the data's PAS at
    correlation > 0.99 (``cal`` starts at the fitted offsets, the run summary says so); with the
    search off, at under 0.5."""
    from types import SimpleNamespace

    from rfmitsuba.core import config as C
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.base import Views, render
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField
    from rfmitsuba.train.config import TrainConfig

    from los_data import F as F920, los_spectra

    true = np.random.default_rng(3).uniform(-np.pi, np.pi, 16)
    pas, x, y = los_spectra(offsets_rad=true, n=24)
    data = SimpleNamespace(path="stub", train=np.arange(len(x)), rx_to_world=None, frequency_hz=F920, measured=False,
                           readout="phase_only", task="tx", positions=lambda idx: (x[idx], y[idx], y[idx]),
                           pas=lambda idx, d=1: pas[idx] if d == 2 else None)
    views = Views(antenna_pos=y, view_pos=x, transmitter=y, rx_to_world=None, frequency_hz=F920, task="tx")
    corr = {}
    for mode in ("auto", "off"):
        cfg = C.override(TrainConfig(), ['model="coherent_gaussians"', "coherent_gaussians.images=0",
                                         "coherent_gaussians.scatterers=0", 'coherent_gaussians.frame_search="off"',
                                         "coherent_gaussians.coupling=false",
                                         f'coherent_gaussians.calibration_search="{mode}"'])
        f = CoherentGaussianField.for_training(cfg, data, scene_xml=None)
        img = np.asarray(render([f], views, height=45, width=180))
        a = img.reshape(len(x), -1) - img.reshape(len(x), -1).mean(1, keepdims=True)
        b = pas.reshape(len(x), -1) - pas.reshape(len(x), -1).mean(1, keepdims=True)
        corr[mode] = float(np.mean((a * b).sum(1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)))
        cal = np.asarray(f.params["cal"].numpy()).reshape(16, 2)
        if mode != "off":
            rep = f.init_report["calibration_fit"]
            assert rep["applied"] and rep["score"] > 0.99 > 0.5 > rep["stated_score"]
            np.testing.assert_allclose(cal[:, 0] + 1j * cal[:, 1], np.exp(1j * np.radians(rep["phase_deg"])), atol=1e-5)
            assert f.starts_advised == 2        # a searched calibration: two training starts
        else:
            assert "calibration_fit" not in f.init_report and np.allclose(cal, [1.0, 0.0])
            assert f.starts_advised == 1
    assert corr["auto"] > 0.99 and corr["off"] < 0.5
    # with the coupling left to "auto", phase-only spectra learn it, and a learned coupling also
    # trains from two starts
    cfg = C.override(TrainConfig(), ['model="coherent_gaussians"', "coherent_gaussians.images=0",
                                     "coherent_gaussians.scatterers=0", 'coherent_gaussians.frame_search="off"',
                                     'coherent_gaussians.calibration_search="off"'])
    f = CoherentGaussianField.for_training(cfg, data, scene_xml=None)
    assert f.cfg.coupling is True and "coupling" in f.params and f.starts_advised == 2
    with pytest.raises(ConfigError, match="calibration_search"):
        CoherentGaussianConfig(calibration_search="on")
    with pytest.raises(ConfigError, match="calibration_min_gain"):
        CoherentGaussianConfig(calibration_min_gain=float("nan"))
