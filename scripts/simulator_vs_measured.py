"""Simulated folders beside a measured one, figure by figure: the table and figure of
docs/results/measured/simulator.md.

Usage: python scripts/simulator_vs_measured.py MEASURED --pitch-m 0.16 --out OUT_DIR NAME=FOLDER [NAME=FOLDER ...]

Profiles every folder with :func:`rfmitsuba.eval.folder_profile.profile` (floors on the folder's own
split and on the spatial block, the co-array fit, the line-of-sight correlation, SSIM against the
distance between tags) and writes ``simulator_table.md`` (one column per folder, the measured one
first), ``simulator.json`` and ``simulator_ssim_by_distance.png``. Profiles are kept in OUT_DIR/profiles/ and
not made again.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("measured", type=Path)
    ap.add_argument("folders", nargs="+", help="NAME=FOLDER of each simulated folder")
    ap.add_argument("--pitch-m", type=float, default=None, help="the measured array's element pitch [m]")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()

    from rfmitsuba.core import plots
    from rfmitsuba.eval.folder_profile import profile

    cache = a.out / "profiles"
    cache.mkdir(parents=True, exist_ok=True)
    named = [("measured", a.measured, a.pitch_m)]
    for item in a.folders:
        name, _, folder = item.partition("=")
        if not folder:
            raise SystemExit(f"expected NAME=FOLDER, got {item!r}")
        named.append((name, Path(folder), None))
    profiles = {}
    for name, folder, pitch in named:
        f = cache / f"{name}.json"
        if not f.is_file():
            f.write_text(json.dumps(profile(folder, pitch_m=pitch), indent=1))
        profiles[name] = json.loads(f.read_text())
    (a.out / "simulator.json").write_text(json.dumps(profiles, indent=1))

    names = list(profiles)
    rows = []
    for split in ("dataset", "block"):
        for k, label in (("nearest_neighbour", "nearest neighbour"), ("idw3", "IDW-3"), ("mean_image", "mean image")):
            rows.append((f"{split} split: {label}, mean / median",
                         [f"{p['floors'][split][k]['mean']:.3f} / {p['floors'][split][k]['median']:.3f}"
                          for p in profiles.values()]))
    rows.append(("co-array fit, re-render SSIM", [f"{p['coarray_fit']:.3f}" for p in profiles.values()]))
    rows.append(("line-of-sight correlation, stated frame / best frame",
                 [f"{p['line_of_sight']['stated']:.3f} / {p['line_of_sight']['best']:.3f}" for p in profiles.values()]))
    first = profiles[names[0]]["ssim_by_distance"]
    edges = first["edges_m"]
    for i in range(len(edges) - 1):
        cells = []
        for p in profiles.values():
            s = p["ssim_by_distance"]["ssim"][i]
            cells.append("–" if s is None else f"{s:.3f}")
        rows.append((f"SSIM of two spectra {100 * edges[i]:.0f}–{100 * edges[i + 1]:.0f} cm apart", cells))
    lines = ["| figure | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    lines += [f"| {label} | " + " | ".join(cells) + " |" for label, cells in rows]
    (a.out / "simulator_table.md").write_text("\n".join(lines) + "\n")

    fig, ax = plots.subplots(1, 1, figsize=(6.5, 4))
    mids = [100 * (lo + hi) / 2 for lo, hi in zip(edges[:-1], edges[1:])]
    for name, p in profiles.items():
        ax.plot(mids, p["ssim_by_distance"]["ssim"], "o-" if name == "measured" else ".--", label=name)
    ax.set_xscale("log")
    plots.label(ax, xlabel="distance between the two tags (cm)", ylabel="mean SSIM of their spectra")
    plots.save(fig, a.out / "simulator_ssim_by_distance.png")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
