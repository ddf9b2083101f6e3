"""rfmitsuba plugins (installed as :mod:`rfmitsuba.plugins`).

Plugins extend Mitsuba/Sionna RT through their registries, so that scene XML
can name them:

- ``body-tissue`` (:mod:`rfmitsuba.plugins.body_tissue`): a radio material for people.

Call :func:`register` once before loading a scene that uses them (it is
idempotent; it selects the default Mitsuba variant if none is active).
"""
from __future__ import annotations

_registered: set[str] = set()


def register() -> list[str]:
    """Register every plugin with Mitsuba for the active variant; returns the plugin names.

    Safe to call many times: each variant is registered once.
    """
    from rfmitsuba.core import backend

    variant = backend.variant()
    from . import body_tissue

    if variant not in _registered:
        body_tissue.register()
        _registered.add(variant)
    return [body_tissue.PLUGIN_NAME]
