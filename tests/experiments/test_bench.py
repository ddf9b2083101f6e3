"""Tests of the splat benchmark (rfmitsuba.experiments.bench, rfmitsuba.cli.bench) and of
the PyTorch baseline it compares against (rfmitsuba.splat.torch_baseline)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from rfmitsuba.cli import main
from rfmitsuba.experiments import bench
from rfmitsuba.splat import reference as ref


def test_torch_baseline_matches_reference():
    torch = pytest.importorskip("torch")
    from rfmitsuba.splat import torch_baseline

    (means, ls, rot, op, sig), rx = bench.make_scene(150, seed=3)
    img = torch_baseline.render(torch, *(torch.tensor(a) for a in (means, ls, rot, op, sig)),
                                torch.tensor(rx[0], dtype=torch.float32), height=18, width=72)
    expected, amb = ref.render(means, ls, rot, op, sig, rx, height=18, width=72, ambiguous=True)
    assert np.abs(np.where(amb[0], 0, img.detach().numpy() - expected[0])).max() < 1e-4


def test_cli_quick_prints_table_and_json(tmp_path, capsys, quick_dataset):
    out = tmp_path / "bench.json"
    assert main(["bench", "splat", "--quick", "--dataset", str(quick_dataset.path), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    # the Stage-1 splat step, both ways of running the networks' products, with their ratio
    step = json.loads(out.read_text())["stage1_step"]
    assert step["gaussians"] == 2000 and step["batch"] == 4
    for side in ("host", "coop_vec", "host_45x180"):
        assert step[side]["model"] == "splat" and step[side]["batch"] == 4 and step[side]["step_ms"] > 0
    assert step["host"]["downsample"] == 1 and step["host_45x180"]["downsample"] == 2
    assert "Stage-1 splat step, 2000 Gaussians, batch 4" in text and "as cooperative vectors" in text
    assert "the same at 45x180 (downsample 2" in text
    assert "Dr.Jit fwd" in text and "compile time of a first iteration" in text
    result = json.loads(out.read_text())
    assert f"{result['tile_lanes']} rasteriser lanes per tile" in text and result["tile_lanes"] in (8, 16, 32, 64)
    row = result["rows"][0]
    assert row["n"] == bench.QUICK_SIZES[0]
    for key in ("forward_ms", "backward_ms", "iteration_ms", "peak_mib"):
        assert row["drjit"][key] >= 0
    assert row["drjit"]["forward_ms"] > 0 and row["drjit"]["iteration_ms"] > 0
    assert result["compile"]["cold_ms"] >= 0 and result["compile"]["warm_ms"] >= 0
    if bench.torch_available():
        assert "speed-up" in text and row["torch"]["iteration_ms"] > 0
    else:
        assert "PyTorch is missing" in text


def test_cli_rejects_bad_sizes(capsys):
    assert main(["bench", "splat", "--sizes", "10,x"]) == 2
    assert "--sizes" in capsys.readouterr().err
    assert main(["bench", "splat", "--sizes", "0"]) == 2


def test_report_without_torch_says_so():
    result = {"height": 90, "width": 360, "repeats": 5, "cores": 2, "load": (1.0, 1.0, 1.0),
              "torch": False, "torch_note": "missing",
              "rows": [{"n": 10, "drjit": {"forward_ms": 1.0, "backward_ms": 2.0, "iteration_ms": 4.0,
                                           "peak_mib": 1.0}}],
              "compile": {"cold_ms": 1500.0, "warm_ms": 50.0, "n": 2000}}
    text = bench.format_report(result)
    assert "PyTorch is missing" in text and "speed-up" not in text
    assert "empty kernel cache 1.50 s, warm cache 0.05 s" in text


def test_times_ms_runs_for_at_least_min_time(monkeypatch):
    # A figure takes max(repeats, enough calls to last min_time_s) calls, never more than
    # MAX_CALLS: a fast kernel's median then spans as long a stretch of the machine as a slow
    # reference's. A fake clock makes the count exact.
    clock = {"t": 0.0}
    monkeypatch.setattr(bench.time, "perf_counter", lambda: clock["t"])

    def call(dt):
        def fn():
            clock["t"] += dt
        return fn

    assert len(bench.times_ms(call(0.25), 5, warmup=0, min_time_s=1.0)) == 5       # 1.25 s already
    # (steps of 1/64 s: binary fractions, so the sums are exact)
    assert len(bench.times_ms(call(1 / 64), 5, warmup=0, min_time_s=1.0)) == 64
    assert len(bench.times_ms(call(1 / 64), 5, warmup=0)) == 5                     # no minimum
    monkeypatch.setattr(bench, "MAX_CALLS", 30)
    assert len(bench.times_ms(call(1 / 64), 5, warmup=0, min_time_s=1.0)) == 30
    cpu: list = []
    assert bench.times_ms(call(1 / 32), 3, warmup=1, cpu=cpu, min_time_s=0.25) == [31.25] * 8 and len(cpu) == 8
