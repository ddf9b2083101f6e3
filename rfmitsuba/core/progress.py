"""Progress bars for long work (tqdm), quiet under ``RFMITSUBA_QUIET=1`` or ``quiet=True``."""
from __future__ import annotations

import os

from tqdm.auto import tqdm


def bar(total: int | None = None, *, desc: str = "", unit: str = "it", quiet: bool = False, **kw) -> tqdm:
    """A tqdm bar showing rate and ETA; disabled when quiet."""
    disable = quiet or os.environ.get("RFMITSUBA_QUIET", "") not in ("", "0")
    return tqdm(total=total, desc=desc, unit=unit, disable=disable, dynamic_ncols=True, **kw)
