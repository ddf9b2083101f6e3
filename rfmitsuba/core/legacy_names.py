"""Names that changed, so that files written before still read: one word for one thing.

The moving body in a room was called "human" in some names and "person" in others; it is
"person" everywhere now (``person_pos``, ``person_positions``, ``SplatPersonConfig.person_octaves``,
the method ``baseline_person``, the field format ``rfmitsuba-coherent-person-field/1``). Readers
of saved files (dataset ``meta.json`` and ``split.json``, field states, run configurations) pass
the names they read through :func:`current_name` / :func:`current_keys`; writers write the new
names only.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any

#: (old word, new word), longest first; matched inside names (``num_humans`` -> ``num_people``)
OLD_WORDS = (("humans", "people"), ("human", "person"))
_PATTERN = re.compile("|".join(old for old, _ in OLD_WORDS))
_NEW = dict(OLD_WORDS)


def current_name(name: str) -> str:
    """``name`` with every old word replaced by its new one (``"human_pos"`` -> ``"person_pos"``)."""
    return _PATTERN.sub(lambda m: _NEW[m.group(0)], name) if isinstance(name, str) else name


def folder_written_before(path: str | Path) -> Path:
    """``path`` where it exists; else where a folder written before put it, its components named
    with the old words (``jobs/bedroom_rx/baseline_human_s0`` for ``.../baseline_person_s0``), where
    that exists; else ``path``."""
    path = Path(path)
    if path.exists() or path.parent == path:
        return path
    parent = folder_written_before(path.parent)
    if parent.is_dir():
        for p in sorted(parent.iterdir()):
            if p.name != path.name and current_name(p.name) == path.name:
                return p
    return parent / path.name


def current_keys(obj: Any) -> Any:
    """A copy of a JSON-like object whose dict keys, at every depth, are :func:`current_name` d
    (values are kept as they are)."""
    if isinstance(obj, dict):
        return {current_name(k): current_keys(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [current_keys(v) for v in obj]
    return obj
