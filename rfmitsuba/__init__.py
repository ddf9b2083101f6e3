"""rfmitsuba: radio-field reconstruction with differentiable Gaussian fields.

Importing the package points Dr.Jit at a libLLVM >= 16 (``DRJIT_LIBLLVM_PATH``)
before Dr.Jit starts; import :mod:`rfmitsuba` before :mod:`drjit` or
:mod:`mitsuba`. The Mitsuba/Dr.Jit variant is chosen on first use, see
:mod:`rfmitsuba.core.backend`.

The public API, imported on first use::

    from rfmitsuba import generate, train, evaluate, predict, open_dataset
    from rfmitsuba import GenerateConfig, TrainConfig

``generate`` simulates a dataset (:func:`rfmitsuba.sim.generate.generate`), ``train`` fits a
Stage-1 field (the package :mod:`rfmitsuba.train` is callable as
:func:`rfmitsuba.train.trainer.train`), ``evaluate`` scores a run against the
floors (:func:`rfmitsuba.eval.run.evaluate_run`), ``predict`` renders a run at positions
(:func:`rfmitsuba.eval.predict.predict_run`) and ``open_dataset`` opens a dataset, NeRF2
or One Walk folder (:func:`rfmitsuba.data.store.open_dataset`).
"""
from .core import _llvm

_llvm.configure()

__version__ = "0.1.0"

from .core.backend import set_variant, variant  # noqa: E402

#: the public API: name -> (module, attribute), imported on first use (``import rfmitsuba`` stays light)
_API = {"generate": ("rfmitsuba.sim.generate", "generate"),
        "GenerateConfig": ("rfmitsuba.sim.generate", "GenerateConfig"),
        "TrainConfig": ("rfmitsuba.train.config", "TrainConfig"),
        "evaluate": ("rfmitsuba.eval.run", "evaluate_run"),
        "predict": ("rfmitsuba.eval.predict", "predict_run"),
        "open_dataset": ("rfmitsuba.data.store", "open_dataset")}

__all__ = ["set_variant", "variant", "__version__", "train", *_API]


def __getattr__(name: str):
    if name == "train":   # the subpackage, which calls rfmitsuba.train.trainer.train (rfmitsuba/train/__init__.py)
        import importlib

        return importlib.import_module("rfmitsuba.train")
    if name in _API:
        import importlib

        module, attr = _API[name]
        value = getattr(importlib.import_module(module), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'rfmitsuba' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API) | {"train"})
