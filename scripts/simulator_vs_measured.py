"""Simulated folders beside a measured one, figure by figure: the table and figure of
docs/results/measured/simulator.md.

Usage: python scripts/simulator_vs_measured.py MEASURED --pitch-m 0.16 --out OUT_DIR NAME=FOLDER [NAME=FOLDER ...]
       [--train RUNS_DIR [--time-limit-s 500]]

Profiles every folder with :func:`rfmitsuba.eval.folder_profile.profile` (floors on the folder's own
split and on the spatial block, the co-array fit, the line-of-sight correlation, SSIM against the
distance between tags) and writes ``simulator_table.md`` (one column per folder, the measured one
first), ``simulator.json`` and ``simulator_ssim_by_distance.png``. Profiles are kept in OUT_DIR/profiles/ and
not made again.

With ``--train RUNS_DIR`` it also runs the default model on every folder and both splits, as a user
runs it (``rfmitsuba train FOLDER --out RUNS_DIR/<name>/<split>_s0 --set split=<split>`` then
``rfmitsuba eval``, resumable; see ``measured_fields.run_one``), and adds its mean / median test SSIM,
its margin to the best floor and what ``auto`` chose to the table: does a simulated folder rank the
default against the floors as the measured folder does?
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
    ap.add_argument("--train", type=Path, default=None, metavar="RUNS_DIR",
                    help="also train and evaluate the default model on every folder and both splits, here")
    ap.add_argument("--time-limit-s", type=float, default=500.0, help="each training's wall-clock budget [s]")
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
    if a.train is not None:
        from measured_fields import run_one

        for name, folder, _ in named:
            p = profiles[name]
            p["default_model"] = {}
            for split in ("dataset", "block"):
                run = a.train / name.replace(" ", "_").replace("/", "_") / f"{split}_s0"
                m = run_one(folder, run, split, 0, a.time_limit_s)
                best = max(m[k]["mean"] for k in ("nearest_neighbour", "idw3", "mean_image"))   # the run's own floors
                chosen = json.loads((run / "final" / "summary.json").read_text())["model"]
                p["default_model"][split] = {"mean": m["model"]["mean"], "median": m["model"]["median"],
                                             "margin_to_best_floor": m["model"]["mean"] - best, "chosen": chosen}
    # the folders by name: the page says how each was made, not where it lay
    (a.out / "simulator.json").write_text(json.dumps(
        {k: p | {"folder": Path(p["folder"]).name} for k, p in profiles.items()}, indent=1))

    names = list(profiles)
    rows = []
    for split in ("dataset", "block"):
        for k, label in (("nearest_neighbour", "nearest neighbour"), ("idw3", "IDW-3"), ("mean_image", "mean image")):
            rows.append((f"{split} split: {label}, mean / median",
                         [f"{p['floors'][split][k]['mean']:.3f} / {p['floors'][split][k]['median']:.3f}"
                          for p in profiles.values()]))
    if a.train is not None:
        for split in ("dataset", "block"):
            rows.append((f"{split} split: the default model, mean / median (margin to the best floor)",
                         [f"{p['default_model'][split]['mean']:.3f} / {p['default_model'][split]['median']:.3f} "
                          f"({p['default_model'][split]['margin_to_best_floor']:+.3f})" for p in profiles.values()]))
            rows.append((f"{split} split: what `auto` chose",
                         [p["default_model"][split]["chosen"] for p in profiles.values()]))
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
