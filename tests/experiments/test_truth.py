"""Tests of rfmitsuba.experiments.truth: the comparison measures on hand-made channels, and the
whole experiment (both truths generated, table, figure) on a tiny box room."""
import json

import numpy as np
import pytest

from rfmitsuba import cli
from rfmitsuba.core.errors import ConfigError
from rfmitsuba.experiments import truth as T
from rfmitsuba.rf import array as antenna

F = 2.4e9


def _plane_wave(u):
    return np.exp(1j * 2 * np.pi / antenna.wavelength(F) * antenna.element_positions(F) @ u)[None]


def test_compare_channels_measures():
    h = _plane_wave(np.array([0.6, 0.0, 0.8])) + 0.5 * _plane_wave(np.array([0.0, -0.6, 0.8]))
    c = T.compare_channels(h, 2 * h * np.exp(0.7j), frequency_hz=F)  # gain and common phase only
    assert c["correlation"][0] == pytest.approx(1, abs=1e-6)
    assert c["power_db"][0] == pytest.approx(20 * np.log10(2), abs=1e-6)
    assert c["ssim"][0] == pytest.approx(1, abs=1e-6)
    other = _plane_wave(np.array([-0.6, 0.0, 0.8])) + 0.5 * _plane_wave(np.array([0.0, -0.6, 0.8]))
    c = T.compare_channels(h, other, frequency_hz=F)
    assert c["correlation"][0] < 0.9 and c["ssim"][0] < 0.9 and c["power_db"][0] == pytest.approx(0, abs=1e-6)
    with pytest.raises(ConfigError, match="one shape"):
        T.compare_channels(h, h[:, :8], frequency_hz=F)
    with pytest.raises(ConfigError, match="zero"):
        T.compare_channels(h, 0 * h, frequency_hz=F)
    s = T.summarise(np.arange(11.0))
    assert (s["mean"], s["median"], s["p10"], s["min"], s["max"]) == (5, 5, 1, 0, 10)


def test_truth_uncertainty_box_room(variant, box_room, tmp_path):
    cfg = T.TruthConfig(scene=str(box_room), positions=3, samples=2000)
    res = T.truth_uncertainty(tmp_path / "t", cfg, quiet=True)
    assert res["count"] == 3 and len(res["per_pas"]) == 3
    for k in ("ssim", "correlation"):
        st = res["stats"][k]
        assert 0 < st["min"] <= st["p10"] <= st["median"] <= st["max"] <= 1 + 1e-9
    assert json.loads((tmp_path / "t" / "exact" / "meta.json").read_text())["generate"]["array"] == "exact"
    md = (tmp_path / "t" / "table.md").read_text()
    assert "| PAS SSIM (metric protocol) |" in md and "Regenerate: `rfmitsuba experiment truth" in md
    assert "Ray-sampling share" in md and res["noise"]["solver_seeds"] == [42, 43]
    assert 0 < res["noise"]["stats"]["ssim"]["min"] <= 1 + 1e-9
    assert (tmp_path / "t" / "truth_ssim.png").stat().st_size > 0
    with pytest.raises(ConfigError, match="at most"):
        T.truth_uncertainty(tmp_path / "u", T.TruthConfig(positions=10_000), quiet=True)


def test_truth_cli_options(tmp_path, capsys):
    assert cli.main(["experiment", "truth", str(tmp_path / "ds"), "--out", str(tmp_path / "o")]) == 2
    assert "--scene" in capsys.readouterr().err
    assert cli.main(["experiment", "truth", "--positions", "0", "--out", str(tmp_path / "o")]) == 2
    assert "--positions" in capsys.readouterr().err
    assert cli.main(["experiment", "motivation", "--out", str(tmp_path / "o")]) == 2
    assert "needs a dataset" in capsys.readouterr().err
