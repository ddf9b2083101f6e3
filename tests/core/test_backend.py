"""Tests of rfmitsuba.core.backend: one variant for Sionna RT and the kernels."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from rfmitsuba.core import backend


def test_llvm_variant_types(variant):
    assert mi.variant() == variant
    x = backend.Float([1.0, 2.0, 3.0])
    assert type(x) is mi.Float  # the same JIT arrays as the ray tracer
    assert dr.allclose(dr.sum(x * x), 14.0)


def test_alias_and_unknown(variant):
    assert backend.set_variant("llvm") == "llvm_ad_mono_polarized"
    with pytest.raises(ValueError, match="unknown Mitsuba variant 'nope'"):
        backend.set_variant("nope")
    assert backend.variant() == "llvm_ad_mono_polarized"


@pytest.mark.skipif(not backend.cuda_available(), reason="no CUDA device")
def test_cuda_variant():  # pragma: no cover - runs on GPU machines only
    before = backend.variant()
    try:
        assert backend.set_variant("cuda").startswith("cuda")
        assert backend.is_cuda()
    finally:
        backend.set_variant(before)


@pytest.mark.parametrize("reduce", [False, True])
def test_sincos_phase_is_accurate_for_path_phases(variant, monkeypatch, reduce):
    """Path phases reach thousands of radians. ``reduce`` forces the argument reduction that the
    CUDA backend takes (its fast sine errs by about 1.4e-7 * |phase|), here on the active backend's
    arithmetic; values and derivatives within 1e-6 of float64 up to 4000 rad."""
    if reduce:
        monkeypatch.setattr(backend, "is_cuda", lambda: True)
    x = np.linspace(-4000.0, 4000.0, 400_001).astype(np.float32)
    X = backend.Float(x)
    dr.enable_grad(X)
    s, c = backend.sincos_phase(X)
    x64 = x.astype(np.float64)
    assert np.abs(np.asarray(s.numpy(), np.float64) - np.sin(x64)).max() < 1e-6
    assert np.abs(np.asarray(c.numpy(), np.float64) - np.cos(x64)).max() < 1e-6
    dr.backward(dr.sum(s))
    assert np.abs(np.asarray(dr.grad(X).numpy(), np.float64) - np.cos(x64)).max() < 1e-6
