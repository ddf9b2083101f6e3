"""Training: configuration, the loop and run folder, the loss, density strategies.

The package is also the public ``rfmitsuba.train``: calling it trains a Stage-1 field,
``rfmitsuba.train(dataset, out, cfg=...)`` being :func:`rfmitsuba.train.trainer.train` (a package
and a function of one name cannot both be attributes of ``rfmitsuba``, so the package calls the
function).
"""
import sys as _sys
import types as _types


class _TrainPackage(_types.ModuleType):
    def __call__(self, *args, **kwargs):
        """:func:`rfmitsuba.train.trainer.train`."""
        from .trainer import train

        return train(*args, **kwargs)


_sys.modules[__name__].__class__ = _TrainPackage
