"""Regenerate the built-in rooms in scenes/ from rfmitsuba.scenes.catalog.

Usage: python scripts/build_scenes.py [--out DIR] [NAME ...]

Deterministic: running it twice gives byte-identical files (tests/test_scenes.py
checks the checked-in files against a fresh build). Old meshes of a room are
removed before it is written, so renamed shapes leave nothing stale behind.
"""
from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from rfmitsuba.sim import scene_builder
from rfmitsuba.scenes import catalog

ROOT = Path(__file__).resolve().parent.parent


def build(out: Path, names: list[str]) -> list[Path]:
    """Write each named room to ``out/<name>/``; returns the XML paths."""
    paths = []
    for name in names:
        desc = catalog.ROOMS[name]()
        folder = out / name
        scene_builder.validate(desc)                 # fail before touching the old files
        if (folder / "meshes").is_dir():
            shutil.rmtree(folder / "meshes")
        p = scene_builder.write_scene(desc, folder, overwrite=True)
        print(f"{p}: {len(scene_builder.shape_ids(desc))} shapes, "
              f"{scene_builder.triangle_count(desc)} triangles")
        paths.append(p)
    return paths


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "scenes", help="output folder (default: scenes/)")
    ap.add_argument("names", nargs="*", help="rooms to build (default: all)")
    args = ap.parse_args(argv)
    names = args.names or list(catalog.ROOMS)
    unknown = [n for n in names if n not in catalog.ROOMS]
    if unknown:
        print(f"unknown room(s) {', '.join(unknown)}; known: {', '.join(catalog.ROOMS)}", file=sys.stderr)
        return 2
    build(args.out, names)
    return 0


if __name__ == "__main__":
    sys.exit(main())
