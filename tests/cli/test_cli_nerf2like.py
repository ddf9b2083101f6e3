"""CLI ``rfmitsuba nerf2like``: a small NeRF2-like folder that ``train`` reads as phase-only data."""


def test_nerf2like_cli_writes_a_folder_train_reads(tmp_path, capsys):
    from rfmitsuba.cli import main
    from rfmitsuba.data.views import TrainData

    out = tmp_path / "n2"
    assert main(["nerf2like", "--out", str(out), "--tags", "12", "--snr", "30", "--quiet"]) == 0
    assert "rfmitsuba train" in capsys.readouterr().out
    data = TrainData.open(out)
    assert data.readout == "phase_only" and not data.measured and data.task == "tx"
    assert len(data.train) + len(data.test) == 12 and abs(data.frequency_hz - 920e6) < 1
    assert main(["nerf2like", "--out", str(out), "--tags", "0"]) == 2  # bad input: exit code 2, reason on stderr
    assert "num_tags" in capsys.readouterr().err


def test_nerf2like_cli_position_error_is_in_millimetres(tmp_path):
    import json

    from rfmitsuba.cli import main

    out = tmp_path / "n2"
    assert main(["nerf2like", "--out", str(out), "--tags", "12", "--position-error", "5", "--quiet"]) == 0
    rec = json.loads((out / "rfmitsuba.json").read_text())
    assert rec["config"]["position_error_m"] == 0.005
    assert rec["impairments"]["position_error"]["sigma_m_per_axis"] == 0.005
