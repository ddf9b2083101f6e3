"""rfmitsuba.eval.invert and ``rfmitsuba invert``: on synthetic 8-bit spectra whose channels,
carrier, pitch and grid are known, the inversion finds all four."""
from __future__ import annotations

import json

import numpy as np
import pytest

from rfmitsuba.eval import invert as inv
from rfmitsuba.rf import coarray
from rfmitsuba.rf.array import SPEED_OF_LIGHT

F = 920e6
PITCH = 0.16


def _spectra(n: int, *, e0: float, seed: int = 0, f_hz: float = F, pitch: float = PITCH):
    rng = np.random.default_rng(seed)
    h = rng.normal(size=(n, 16)) + 1j * rng.normal(size=(n, 16))
    img = inv.channel_images(h, inv.Geometry(f_hz, pitch, e0))
    return h, np.round(img * 255) / 255


def test_scan_finds_the_grid_and_the_electrical_pitch():
    _, imgs = _spectra(3, e0=0.0, f_hz=940e6)
    best, rows = inv.scan_geometry(imgs, frequency_hz=F, pitch_m=PITCH,
                                   pitch_wavelengths=np.arange(0.46, 0.5201, 0.01))
    assert best.elevation_start_deg == 0.0
    # 940 MHz at 0.16 m is 0.5017 wavelengths; the scan's step is 0.01
    assert best.pitch_wavelengths == pytest.approx(PITCH * 940e6 / SPEED_OF_LIGHT, abs=0.006)
    assert best.frequency_hz == pytest.approx(940e6, rel=0.012)
    assert {r["elevation_start_deg"] for r in rows} == {0.0, 1.0}


def test_invert_images_recovers_the_channels_and_rerenders():
    h, imgs = _spectra(3, e0=0.0, seed=1)
    res = inv.invert_images(imgs, inv.Geometry(F, PITCH, 0.0), starts=32)
    assert res.coarray_ssim.min() > 0.995 and res.channel_ssim.min() > 0.99
    for est, true in zip(res.channels, h):
        assert coarray.channel_error(est, true) < 0.05
    assert np.allclose(np.linalg.norm(res.channels, axis=1), 1.0)
    assert np.all(res.magnitude_ratio < 1.0)


def test_phase_only_channels_have_magnitude_ratio_one():
    rng = np.random.default_rng(2)
    h = np.exp(1j * rng.uniform(-np.pi, np.pi, size=(2, 16)))
    imgs = inv.channel_images(h, inv.Geometry(F, PITCH, 1.0))
    res = inv.invert_images(imgs, inv.Geometry(F, PITCH, 1.0), starts=32)
    assert res.magnitude_ratio.min() > 0.97


def test_cli_invert_on_a_nerf2_folder(tmp_path):
    from rfmitsuba.cli import main
    from rfmitsuba.data import nerf2

    h, imgs = _spectra(3, e0=0.0, seed=3)
    folder = tmp_path / "measured"
    nerf2.write_spectra(folder, imgs)
    nerf2.write_positions(folder / "tx_pos.csv", np.random.default_rng(0).normal(size=(3, 3)))
    (folder / "gateway_info.yml").write_text("gateway1:\n  position: [5.0, 0.0, 0.0]\n  orientation: [0, 0, 0, 1]\n")
    out = tmp_path / "inv"
    assert main(["invert", str(folder), "--out", str(out), "--pitch-m", "0.16", "--scan-images", "2", "--starts", "32",
                 "--quiet"]) == 0
    summ = json.loads((out / "invert.json").read_text())
    assert summ["implied"]["elevation_start_deg"] == 0.0
    assert summ["used"]["elevation_start_deg"] == 0.0
    assert summ["channel_ssim"]["min"] > 0.99
    assert np.load(out / "channels.npy").shape == (3, 16)
    assert np.load(out / "coefficients.npy").shape == (3, 49)
    assert (out / "invert.png").stat().st_size > 0


def test_cli_invert_names_a_bad_elevation_start(tmp_path, capsys):
    from rfmitsuba.cli import main
    from rfmitsuba.data import nerf2

    _, imgs = _spectra(1, e0=1.0)
    folder = tmp_path / "f"
    nerf2.write_spectra(folder, imgs)
    nerf2.write_positions(folder / "tx_pos.csv", np.zeros((1, 3)))
    (folder / "gateway_info.yml").write_text("gateway1:\n  position: [1, 0, 0]\n  orientation: [0, 0, 0, 1]\n")
    assert main(["invert", str(folder), "--out", str(tmp_path / "o"), "--elevation-start", "top"]) == 2
    assert "--elevation-start" in capsys.readouterr().err
