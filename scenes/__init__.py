"""Built-in rooms (installed as :mod:`rfmitsuba.scenes`).

Each room ``<name>`` is ``scenes/<name>/<name>.xml`` (Mitsuba 3 XML for
Sionna RT) with its meshes in ``scenes/<name>/meshes/*.ply``, generated from
the descriptions in :mod:`rfmitsuba.scenes.catalog` by
``scripts/build_scenes.py``.

>>> from rfmitsuba import scenes
>>> scenes.available()
['bedroom', 'living_room', 'dining_room', 'large_room']
>>> scenes.path("bedroom").name
'bedroom.xml'
"""
from __future__ import annotations

from pathlib import Path

from rfmitsuba.core.errors import SceneError

_HERE = Path(__file__).resolve().parent


def available() -> list[str]:
    """Names of the built-in rooms whose XML is present."""
    from .catalog import ROOMS

    return [n for n in ROOMS if (_HERE / n / f"{n}.xml").is_file()]


def path(name: str) -> Path:
    """Path of the XML of built-in room ``name``; :class:`SceneError` for an unknown name."""
    names = available()
    if name not in names:
        raise SceneError(f"unknown scene {name!r}; built-in scenes: {', '.join(names)}")
    return _HERE / name / f"{name}.xml"


def description(name: str):
    """The :class:`rfmitsuba.sim.scene_builder.RoomDescription` that built room ``name``."""
    from .catalog import ROOMS

    if name not in ROOMS:
        raise SceneError(f"unknown scene {name!r}; built-in scenes: {', '.join(ROOMS)}")
    return ROOMS[name]()
