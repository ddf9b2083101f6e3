"""The documentation's relative links (README, docs/, notebooks/README) point at files that exist.

The README links the committed reports under docs/results/ and the lab notes docs/lab-notes/;
moving or renaming one of them must not leave a user with a dead link."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", ROOT / "notebooks" / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
LINK = re.compile(r"\]\(([^)\s]+)\)")


def relative_links(text: str) -> list[str]:
    """Targets of the Markdown links ``[text](target)`` in ``text`` that are paths (no URL scheme,
    no bare ``#anchor``), without their ``#anchor``."""
    out = []
    for target in LINK.findall(text):
        if re.match(r"[A-Za-z][A-Za-z0-9+.-]*:", target) or target.startswith("#"):
            continue
        out.append(target.split("#", 1)[0])
    return out


def test_relative_links_finds_paths_only():
    text = "[a](docs/x.md) [b](https://x.org/y) [c](#top) [d](../README.md#set-up) [e](mailto:a@b)"
    assert relative_links(text) == ["docs/x.md", "../README.md"]


@pytest.mark.parametrize("doc", [d for d in DOCS if d.is_file()], ids=lambda d: str(d.relative_to(ROOT)))
def test_relative_links_resolve(doc: Path):
    dead = [t for t in relative_links(doc.read_text(encoding="utf-8")) if not (doc.parent / t).exists()]
    assert not dead, f"{doc.relative_to(ROOT)} links to missing files: {dead}"
