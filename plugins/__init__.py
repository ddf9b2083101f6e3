"""rfmitsuba plugins (installed as :mod:`rfmitsuba.plugins`).

Plugins extend Mitsuba/Sionna RT through their registries, so that scene XML
can name them:

- ``human-tissue`` (:mod:`rfmitsuba.plugins.human_tissue`): a radio material for people.

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
    from . import human_tissue

    if variant not in _registered:
        human_tissue.register()
        _registered.add(variant)
    return [human_tissue.PLUGIN_NAME]
