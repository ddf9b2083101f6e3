"""rfmitsuba: radio-field reconstruction with differentiable Gaussian splatting.

Importing the package points Dr.Jit at a libLLVM >= 16 (``DRJIT_LIBLLVM_PATH``)
before Dr.Jit starts; import :mod:`rfmitsuba` before :mod:`drjit` or
:mod:`mitsuba`. The Mitsuba/Dr.Jit variant is chosen on first use, see
:mod:`rfmitsuba.core.backend`.
"""
from .core import _llvm

_llvm.configure()

__version__ = "0.1.0"

from .core.backend import set_variant, variant  # noqa: E402

__all__ = ["set_variant", "variant", "__version__"]
