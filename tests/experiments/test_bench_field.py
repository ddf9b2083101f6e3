"""rfmitsuba.experiments.bench_field (``rfmitsuba bench field``): the references are the same math as
the Dr.Jit kernels, every figure the report names is measured, and bad options are refused."""
from __future__ import annotations

import json

import numpy as np
import pytest

from rfmitsuba.cli import main
from rfmitsuba.experiments import bench_field


def test_numpy_bartlett_gradient_is_the_drjit_adjoint(variant):
    """The NumPy reference of the Bartlett benchmark computes what the Dr.Jit op computes: the
    normalised PAS (1e-5) and the gradient of sum(c * PAS) (1e-3 of its largest entry)."""
    r = bench_field.measure_bartlett(views=3, repeats=1)
    assert r["parity"]["pas_max_abs"] < 1e-5
    assert r["parity"]["grad_max_rel"] < 1e-3
    for key in ("drjit_forward", "drjit_forward_backward", "numpy_forward", "numpy_forward_backward"):
        assert r[key]["ms"] > 0 and r[key]["cpu_ms"] >= 0


def test_numpy_bartlett_gradient_matches_finite_differences():
    """The reference adjoint itself, against central differences (float64)."""
    from rfmitsuba.rf.bartlett_ref import beamformer

    rng = np.random.default_rng(4)
    W = beamformer(frequency_hz=2.4e9, resolution_deg=10)
    h = rng.normal(size=(2, 16)) + 1j * rng.normal(size=(2, 16))
    c = rng.normal(size=(2, len(W)))
    g = bench_field.numpy_bartlett_gradient(h, W, c)
    f = lambda hh: float((bench_field.numpy_bartlett(hh, W)[2] * c).sum())  # noqa: E731
    for k in (0, 5, 17, 31):
        e = np.zeros(h.shape, complex)
        e.flat[k] = 1e-6
        assert g.flat[k].real == pytest.approx((f(h + e) - f(h - e)) / 2e-6, rel=1e-4, abs=1e-6)
        assert g.flat[k].imag == pytest.approx((f(h + 1j * e) - f(h - 1j * e)) / 2e-6, rel=1e-4, abs=1e-6)


def test_benchmark_field_is_generic(variant):
    """Direct path, the six walls' images up to two reflections, and the scatterers asked for."""
    f = bench_field.make_field(scatterers=5)
    assert f.num_scatterers == 5 and f.num_images > 7
    assert (f.order == 0).sum() == 1 and (f.order == 1).sum() == 6


def test_cli_field_quick_writes_every_figure(variant, quick_dataset, tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert main(["bench", "field", "--quick", "--dataset", str(quick_dataset.path), "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    text = capsys.readouterr().out
    for row in ("field render, 8 views", "field forward + backward", "Bartlett forward + backward",
                "render per PAS, batch 40", "Stage-1 training, coherent_gaussians"):
        assert row in text, row
    assert r["field"]["drjit_forward"]["ms"] > 0
    assert 0 < r["stage1"]["steps_per_s"] < 1e4 and r["stage1"]["steps"] == 30
    # the coherent Gaussian field trains at 45 x 180; the same training at 90 x 360 is the reference
    assert r["stage1"]["downsample"] == 2 and r["stage1_full_res"]["downsample"] == 1
    assert "45x180" in text and "90x360" in text and "as many steps/s" in text
    # and traced every step: the recorded step's reference
    assert r["stage1"]["freeze"] and not r["stage1_traced"]["freeze"] and "every step traced" in text
    if r["field"]["parity"] is not None:  # PyTorch installed: the twin renders the same PAS
        assert r["field"]["parity"]["pas_max_abs"] < 1e-3


def test_cli_bad_options(tmp_path):
    assert main(["bench", "field", "--dataset", str(tmp_path / "missing")]) == 2
    assert main(["bench", "field", "--stage1-config", str(tmp_path / "missing.toml")]) == 2
