"""Run the notebooks and write each as a page of the documentation site, with its figures.

    python scripts/render_notebooks.py [--size tiny|default] [--out docs/notebooks] [NAME ...]

Each notebook of ``notebooks/`` is executed top to bottom (nbclient, a kernel of this
interpreter) at the size asked for (``RFMITSUBA_NOTEBOOK_SIZE``), its files written under a
temporary ``RFMITSUBA_NOTEBOOK_OUT``. The page ``OUT/<name>.md`` holds the notebook's Markdown
cells, its code cells as Python blocks, their printed output as text blocks and their figures as
PNG files beside it (``OUT/<name>/<cell>_<k>.png``). The notebooks themselves stay without
outputs (tests/test_notebooks.py). At ``tiny`` size the four take a few minutes on 2 cores.
"""
from __future__ import annotations

import argparse
import base64
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import nbformat
from nbclient import NotebookClient

ROOT = Path(__file__).resolve().parents[1]
#: most characters of one cell's printed output a page keeps (the rest is cut, with a note)
MAX_TEXT = 4000


def kernel_spec(root: Path) -> str:
    """A kernelspec under ``root`` that runs this interpreter; its name."""
    spec = root / "kernels" / "rfmitsuba-docs"
    spec.mkdir(parents=True, exist_ok=True)
    (spec / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "rfmitsuba docs", "language": "python"}))
    os.environ["JUPYTER_PATH"] = str(root) + (os.pathsep + os.environ["JUPYTER_PATH"]
                                              if os.environ.get("JUPYTER_PATH") else "")
    return "rfmitsuba-docs"


def page(nb, name: str, images: Path, *, size: str, seconds: float) -> str:
    """The Markdown page of executed notebook ``nb``; its figures are written into ``images``."""
    images.mkdir(parents=True, exist_ok=True)
    lines = [f"<!-- written by scripts/render_notebooks.py from notebooks/{name}.ipynb; do not edit -->", "",
             f"*The notebook `notebooks/{name}.ipynb`, run at `RFMITSUBA_NOTEBOOK_SIZE={size}` "
             f"({seconds:.0f} s on {os.cpu_count()} cores). Regenerate: "
             f"`python scripts/render_notebooks.py --size {size} {name}`.*", ""]
    for i, cell in enumerate(nb.cells):
        if cell.cell_type == "markdown":
            lines += [cell.source, ""]
            continue
        if cell.cell_type != "code" or not cell.source.strip():
            continue
        lines += ["```python", cell.source, "```", ""]
        text, k = [], 0
        for out in cell.get("outputs", []):
            kind = out.get("output_type")
            if kind == "stream":
                text.append(out.get("text", ""))
            elif kind in ("display_data", "execute_result"):
                data = out.get("data", {})
                if "image/png" in data:
                    png = images / f"{i:02d}_{k}.png"
                    png.write_bytes(base64.b64decode(data["image/png"]))
                    lines += [f"![figure {k + 1} of cell {i}]({images.name}/{png.name})", ""]
                    k += 1
                elif "text/plain" in data:
                    text.append(data["text/plain"] + "\n")
        body = "".join(text).rstrip()
        if body:
            if len(body) > MAX_TEXT:
                body = body[:MAX_TEXT] + f"\n... ({len(body) - MAX_TEXT} more characters)"
            lines += ["```text", body, "```", ""]
    return "\n".join(lines).rstrip() + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("names", nargs="*", help="notebook names without .ipynb (default: all)")
    p.add_argument("--size", choices=["tiny", "default"], default="tiny")
    p.add_argument("--out", default=str(ROOT / "docs" / "notebooks"))
    a = p.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    names = a.names or sorted(f.stem for f in (ROOT / "notebooks").glob("*.ipynb"))
    with tempfile.TemporaryDirectory(prefix="rfmitsuba-notebooks-") as tmp:
        kernel = kernel_spec(Path(tmp) / "jupyter")
        os.environ.update(RFMITSUBA_NOTEBOOK_SIZE=a.size, RFMITSUBA_NOTEBOOK_OUT=str(Path(tmp) / "out"),
                          RFMITSUBA_QUIET="1")
        os.environ.pop("MPLBACKEND", None)   # the kernel's inline backend draws the figures
        for name in names:
            nb = nbformat.read(ROOT / "notebooks" / f"{name}.ipynb", as_version=4)
            t0 = time.perf_counter()
            NotebookClient(nb, kernel_name=kernel, timeout=900, resources={"metadata": {"path": tmp}}).execute()
            seconds = time.perf_counter() - t0
            (out / f"{name}.md").write_text(page(nb, name, out / name, size=a.size, seconds=seconds))
            print(f"{name}: {seconds:.0f} s -> {out / (name + '.md')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
