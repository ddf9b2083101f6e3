"""MkDocs hook: a unit in brackets after a shape is not a cross-reference.

Docstrings here write shapes and units in brackets, ``float [N, 3] [m]``. Python-Markdown reads
``[N, 3] [m]`` as a reference link to ``m``, which mkdocs-autorefs then reports as an unresolved
cross-reference. This hook drops those reports for targets that cannot be Python objects (no dot
in the identifier); an unresolved reference to a dotted path still fails the strict build.
"""
from __future__ import annotations

import logging
import re

_UNRESOLVED = re.compile(r"Could not find cross-reference target '([^']*)'")


class _UnitFilter(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        m = _UNRESOLVED.search(record.getMessage())
        return not (m and "." not in m.group(1))


def on_pre_build(config) -> None:
    """Filter the handlers of the ``mkdocs`` logger (the strict-mode counter among them), which
    every plugin's records reach."""
    for handler in logging.getLogger("mkdocs").handlers:
        if not any(isinstance(f, _UnitFilter) for f in handler.filters):
            handler.addFilter(_UnitFilter())
