"""``rfmitsuba info``: versions, the libLLVM in use and the active variant."""
from __future__ import annotations

import os
import platform


def register(sub) -> None:
    p = sub.add_parser("info", help="print versions, the libLLVM in use and the Dr.Jit variant")
    p.set_defaults(func=run)


def run(args) -> int:
    from importlib.metadata import PackageNotFoundError, version

    from ..core import backend

    print(f"python      {platform.python_version()} ({platform.machine()})")
    for pkg in ("rfmitsuba", "drjit", "mitsuba", "sionna-rt", "numpy", "numba", "scikit-image", "trimesh"):
        try:
            print(f"{pkg:<11} {version(pkg)}")
        except PackageNotFoundError:
            print(f"{pkg:<11} not installed")
    print(f"libLLVM     {os.environ.get('DRJIT_LIBLLVM_PATH', 'none found')}")
    print(f"variant     {backend.variant()}")
    print(f"cpu cores   {os.cpu_count()}")
    return 0
