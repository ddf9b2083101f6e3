"""Helpers for the tests of finished jobs' ``metrics.json`` (compare and reproduce)."""
from __future__ import annotations

import json
from pathlib import Path


def age_metrics(path: Path) -> dict:
    """Make ``path`` look like metrics of an older evaluation: no "affected" part and a dynamic
    mean of -1 (a value no evaluation gives). Returns the metrics as they were."""
    good = json.loads(Path(path).read_text())
    old = json.loads(Path(path).read_text())
    del old["eval"]["affected"]
    old["eval"]["dynamic"]["model"]["mean"] = -1.0
    Path(path).write_text(json.dumps(old))
    return good
