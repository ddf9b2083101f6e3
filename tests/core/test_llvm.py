"""Tests of rfmitsuba._llvm: finding libLLVM >= 16 before Dr.Jit starts."""
import os

import pytest

from rfmitsuba.core import _llvm


@pytest.mark.parametrize("path, major", [
    ("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1", 19),
    ("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1", 15),
    ("/usr/lib/llvm-17/lib/libLLVM.so", 17),
    ("/opt/homebrew/opt/llvm@18/lib/libLLVM.dylib", 18),
    ("/usr/lib/libfoo.so", None),
])
def test_major_version_from_name(path, major):
    assert _llvm.llvm_major_version(path) == major


def test_found_library_is_new_enough():
    path = _llvm.find_libllvm()
    assert path is not None, _llvm.INSTALL_HINT
    assert _llvm.llvm_major_version(path) >= _llvm.MIN_LLVM_MAJOR


def test_package_import_sets_env():
    assert os.environ["DRJIT_LIBLLVM_PATH"]
    assert _llvm.llvm_major_version(os.environ["DRJIT_LIBLLVM_PATH"]) >= 16


def test_old_library_rejected(monkeypatch, tmp_path):
    old = tmp_path / "libLLVM-14.so.1"
    old.write_bytes(b"")
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(old))
    with pytest.raises(_llvm.LLVMNotFoundError, match="libllvm19"):
        _llvm.configure()


def test_missing_library_names_package(monkeypatch):
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/nonexistent/libLLVM.so.19")
    with pytest.raises(_llvm.LLVMNotFoundError, match="apt-get install libllvm19"):
        _llvm.configure()


def test_require_without_any_library(monkeypatch):
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    monkeypatch.setattr(_llvm, "candidate_libraries", lambda: [(14, "/usr/lib/libLLVM-14.so")])
    with pytest.raises(_llvm.LLVMNotFoundError, match="libllvm19"):
        _llvm.require()
