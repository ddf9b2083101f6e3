"""Shared fixtures: the Dr.Jit/Mitsuba variant, and small session-wide data.

The ``variant`` fixture follows Mitsuba's test suite: tests that need the JIT
take it and run on the LLVM backend (or on CUDA with ``RFMITSUBA_VARIANT=cuda``).
"""
from __future__ import annotations

import os

import pytest

import rfmitsuba  # noqa: F401  (points Dr.Jit at libLLVM before anything imports drjit)

os.environ.setdefault("RFMITSUBA_QUIET", "1")


@pytest.fixture(scope="session")
def variant() -> str:
    """The active Mitsuba variant (``llvm_ad_mono_polarized`` on CPU)."""
    from rfmitsuba import backend

    return backend.set_variant(os.environ.get("RFMITSUBA_VARIANT") or "llvm")
