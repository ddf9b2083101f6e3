"""The documentation site builds in strict mode, and the product speaks about the software only.

``mkdocs build --strict`` fails on a broken link between pages, a page missing from the site, a
docstring reference to a Python object that does not exist, or a CLI reference that cannot be
generated from the parsers."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: process talk that does not belong in the product (the changelog is where dated history goes)
PROCESS_TALK = re.compile(r"\b(sessions?[\s-]+\d+|issues?\s+\d+|this session|" + "development" + r"\s+machine)\b",
                          re.IGNORECASE)
SCANNED = ("rfmitsuba", "tests", "configs", "docs", "scripts", "notebooks")
SUFFIXES = {".py", ".md", ".toml", ".yml", ".yaml", ".txt", ".json", ".jsonl", ".ipynb", ".sh", ".csv"}


def _mkdocs() -> str | None:
    exe = Path(sys.executable).with_name("mkdocs")
    return str(exe) if exe.is_file() else shutil.which("mkdocs")


@pytest.mark.skipif(_mkdocs() is None, reason="mkdocs is not installed (the test extra installs it)")
def test_the_site_builds_in_strict_mode(tmp_path):
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    r = subprocess.run([_mkdocs(), "build", "--strict", "--site-dir", str(tmp_path / "site")], cwd=ROOT,
                       capture_output=True, text=True, env=env, timeout=600)
    warnings = [ln for ln in (r.stdout + r.stderr).splitlines() if ln.startswith(("WARNING", "ERROR"))]
    assert r.returncode == 0, "mkdocs build --strict failed:\n" + "\n".join(warnings or [r.stderr[-2000:]])
    cli = (tmp_path / "site" / "reference" / "cli" / "index.html").read_text(encoding="utf-8")
    from rfmitsuba.cli import COMMANDS

    missing = [c for c in COMMANDS if f"rfmitsuba {c}" not in cli]
    assert not missing, f"the CLI reference lacks {missing}"


def test_the_cli_reference_hook_covers_every_command():
    sys.path.insert(0, str(ROOT / "docs" / "hooks"))
    try:
        import cli_reference
    finally:
        sys.path.pop(0)
    from rfmitsuba.cli import COMMANDS

    text = cli_reference.cli_reference()
    for c in COMMANDS:
        assert f"## `rfmitsuba {c}`" in text
    page = cli_reference.on_page_markdown(f"# CLI\n\n{cli_reference.MARKER}\n", None, None, None)
    assert cli_reference.MARKER not in page and "usage: rfmitsuba train" in page


def _product_files():
    yield ROOT / "README.md"
    for top in SCANNED:
        for p in (ROOT / top).rglob("*"):
            if p.is_file() and p.suffix in SUFFIXES and p.name not in ("changelog.md", Path(__file__).name) and "__pycache__" not in p.parts:
                yield p


def test_the_product_speaks_about_the_software_only():
    """No development-process talk in code, tests, configs, scripts, notebooks, README or docs."""
    hits = []
    for p in _product_files():
        text = p.read_text(encoding="utf-8", errors="ignore")
        for m in PROCESS_TALK.finditer(text):            # the whole text: a phrase may wrap a line
            hits.append(f"{p.relative_to(ROOT)}:{text.count(chr(10), 0, m.start()) + 1}: {m.group(0)!r}")
    assert not hits, f"{len(hits)} lines speak of the development process:\n" + "\n".join(hits[:40])


def test_the_process_talk_pattern():
    # the examples are joined from parts: this file is product too, for any scanner but its own test
    said = [w + " " + n for w, n in (("measured in session", "47"), ("see Issue", "12."), ("the session", "\n46"))]
    assert all(PROCESS_TALK.search(t) for t in said + ["their session-" + "46 time", "in this " + "session"])
    assert not PROCESS_TALK.search("tissue 0.903 vs metal") and not PROCESS_TALK.search("lab run 48")


def test_every_notebook_has_its_page_in_the_site():
    """docs/notebooks/<name>.md, written by scripts/render_notebooks.py from the notebook, for every
    notebook, each in the site's navigation; its figures are beside it."""
    root = Path(__file__).resolve().parents[1]
    nav = (root / "mkdocs.yml").read_text()
    for nb in sorted((root / "notebooks").glob("*.ipynb")):
        md = root / "docs" / "notebooks" / f"{nb.stem}.md"
        assert md.is_file(), f"{md} is missing: run python scripts/render_notebooks.py {nb.stem}"
        text = md.read_text()
        assert f"notebooks/{nb.stem}.ipynb" in text and f"notebooks/{nb.stem}.md" in nav
        for ref in re.findall(r"!\[[^\]]*\]\(([^)]+\.png)\)", text):
            assert (md.parent / ref).is_file(), f"{md}: figure {ref} is missing"
