"""Command-line values that argparse's ``type=int`` lets through wrong: lists of whole numbers,
and counts that must be at least 1."""
from __future__ import annotations

import argparse

from ..core.errors import ConfigError


def whole_numbers(text: str, *, option: str, least: int = 0, example: str = "0,1,2") -> list[int]:
    """``"0,1,2"`` -> [0, 1, 2]; ConfigError naming ``option`` and the entry that is not a whole
    number >= ``least``."""
    out = []
    for tok in (t.strip() for t in text.split(",")):
        if not (tok.isascii() and tok.isdigit()) or int(tok) < least:
            raise ConfigError(f"{option}: {tok!r} is not a whole number >= {least} (comma-separated, e.g. "
                              f"{example})")
        out.append(int(tok))
    return out


def positive_int(text: str) -> int:
    """argparse ``type``: a whole number >= 1 (e.g. ``--batch``)."""
    return _at_least(text, 1)


def nonnegative_int(text: str) -> int:
    """argparse ``type``: a whole number >= 0 (e.g. ``--threads``, where 0 means all cores)."""
    return _at_least(text, 0)


def _at_least(text: str, least: int) -> int:
    tok = text.strip()
    if not (tok.isascii() and tok.isdigit()) or int(tok) < least:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number >= {least}")
    return int(tok)
