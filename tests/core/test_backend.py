"""Tests of rfmitsuba.core.backend: one variant for Sionna RT and the kernels."""
import drjit as dr
import mitsuba as mi
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
