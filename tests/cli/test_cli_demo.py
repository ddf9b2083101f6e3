"""CLI ``rfmitsuba demo`` on a synthetic dataset (no Sionna): report with both evaluations and plots."""
from __future__ import annotations


def test_demo_tiny(synthetic_ds, tmp_path, capsys):
    from rfmitsuba.cli import main

    out = tmp_path / "demo"
    assert main(["demo", "--size", "tiny", "--dataset", str(synthetic_ds), "--out", str(out), "--quiet"]) == 0
    assert f"report: {out / 'report.md'}" in capsys.readouterr().out
    text = (out / "report.md").read_text()
    for row in ("| baseline |", "| ours |", "| end_to_end |", "| nearest neighbour |", "| mean image |"):
        assert row in text
    for png in ("dynamic_grid.png", "ssim_cdf.png"):
        assert (out / png).read_bytes()[:4] == b"\x89PNG"
