"""Find a libLLVM that Dr.Jit's LLVM backend can use, before Dr.Jit starts.

Dr.Jit's LLVM backend needs libLLVM >= 16 (older versions abort with
``Cannot select ... fmaximum``). Dr.Jit reads the path from the environment
variable ``DRJIT_LIBLLVM_PATH`` when it is first imported, so this module must
run before ``import drjit``; :mod:`rfmitsuba` imports it first.
"""
from __future__ import annotations

import glob
import os
import re
import sys

#: Oldest libLLVM major version that Dr.Jit 1.x runs correctly with.
MIN_LLVM_MAJOR = 16

#: What to tell a user who has none.
INSTALL_HINT = (
    "Dr.Jit's LLVM backend needs libLLVM >= 16. On Debian/Ubuntu install it with "
    "'apt-get install libllvm19' (or run 'bash scripts/setup.sh'), or point "
    "DRJIT_LIBLLVM_PATH at a libLLVM.so of version 16 or newer."
)

_SEARCH_DIRS = (
    "/usr/lib/x86_64-linux-gnu",
    "/usr/lib/aarch64-linux-gnu",
    "/usr/lib64",
    "/usr/lib",
    "/usr/local/lib",
    "/opt/homebrew/opt/llvm/lib",
    "/usr/local/opt/llvm/lib",
)


class LLVMNotFoundError(RuntimeError):
    """No libLLVM of a usable version was found."""


def llvm_major_version(path: str) -> int | None:
    """Major version encoded in a libLLVM file name, or ``None`` if unknown.

    Recognises ``libLLVM.so.19.1``, ``libLLVM-19.so``, ``libLLVM.so.19``,
    ``/usr/lib/llvm-19/lib/libLLVM.so`` and ``libLLVM.dylib`` inside an
    ``llvm@19`` prefix.
    """
    name = os.path.basename(path)
    for pattern in (r"libLLVM-(\d+)", r"libLLVM\.so\.(\d+)", r"libLLVM\.(\d+)\.dylib"):
        m = re.search(pattern, name)
        if m:
            return int(m.group(1))
    m = re.search(r"llvm[-@](\d+)", path)
    return int(m.group(1)) if m else None


def candidate_libraries() -> list[tuple[int, str]]:
    """All libLLVM files found in the usual places, as ``(major, path)``, newest first."""
    found: dict[str, int] = {}
    patterns = []
    for d in _SEARCH_DIRS:
        patterns += [os.path.join(d, "libLLVM*.so*"), os.path.join(d, "libLLVM*.dylib")]
    patterns += ["/usr/lib/llvm-*/lib/libLLVM*.so*", "/usr/lib64/llvm*/lib/libLLVM*.so*"]
    for pattern in patterns:
        for path in glob.glob(pattern):
            major = llvm_major_version(path)
            if major is not None and os.path.isfile(path):
                found.setdefault(os.path.realpath(path), major)
    return sorted(((v, p) for p, v in found.items()), reverse=True)


def find_libllvm(*, min_major: int = MIN_LLVM_MAJOR) -> str | None:
    """Path of the newest libLLVM with major version >= ``min_major``, or ``None``."""
    for major, path in candidate_libraries():
        if major >= min_major:
            return path
    return None


def configure(*, strict: bool = False) -> str | None:
    """Set ``DRJIT_LIBLLVM_PATH`` to a usable libLLVM unless the user already set it.

    Returns the path in use. With ``strict=True`` raise :class:`LLVMNotFoundError`
    (naming the package to install) where none is found; otherwise return ``None``
    and let :func:`require` raise when the LLVM backend is first needed.
    """
    current = os.environ.get("DRJIT_LIBLLVM_PATH")
    if current:
        if not os.path.isfile(current):
            raise LLVMNotFoundError(f"DRJIT_LIBLLVM_PATH={current!r} does not exist. {INSTALL_HINT}")
        major = llvm_major_version(current)
        if major is not None and major < MIN_LLVM_MAJOR:
            raise LLVMNotFoundError(
                f"DRJIT_LIBLLVM_PATH={current!r} is libLLVM {major}, older than {MIN_LLVM_MAJOR}. {INSTALL_HINT}")
        return current
    if "drjit" in sys.modules:
        # Too late to steer Dr.Jit; it has already chosen its library.
        return None
    path = find_libllvm()
    if path is None:
        if strict:
            raise LLVMNotFoundError(INSTALL_HINT)
        return None
    os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path


def require() -> str:
    """Return the libLLVM path in use, or raise :class:`LLVMNotFoundError` with the install hint."""
    path = os.environ.get("DRJIT_LIBLLVM_PATH") or find_libllvm()
    if path is None:
        raise LLVMNotFoundError(INSTALL_HINT)
    return path
