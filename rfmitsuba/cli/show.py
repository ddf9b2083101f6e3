"""``rfmitsuba show``: look at a dataset (PAS grid, top view, how much the person changes)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..core import plots


def register(sub) -> None:
    p = sub.add_parser("show", help="write PNGs of a dataset: PAS grid, top view, SSIM empty vs person",
                       description="Writes pas_grid.png (empty vs person vs difference), top_view.png (room, "
                                   "antenna, fixed-device and walk positions), ssim_hist.png (per-image SSIM "
                                   "of empty vs person-present PAS) and summary.json into --out.")
    p.add_argument("dataset", help="dataset folder (rfmitsuba or NeRF2 spectrum format)")
    p.add_argument("--out", required=True, help="folder for the PNGs")
    p.add_argument("--rows", type=int, default=4, help="antenna positions in the PAS grid (default 4)")
    p.set_defaults(func=run)


def ssim_empty_vs_person(ds, *, quiet: bool = False) -> np.ndarray:
    """Per-image SSIM (metric protocol (docs/conventions.md)) between the empty-room PAS and each person-present PAS: float64 [S-1, A]."""
    from ..core import progress
    from ..core.ssim import ssim_images
    from ..rf.bartlett_ref import normalize

    empty = normalize(np.asarray(ds.pas(0)))
    out = np.empty((ds.num_states - 1, ds.num_antennas))
    with progress.bar(ds.num_states - 1, desc="SSIM empty vs person", unit="state", quiet=quiet) as pb:
        for s in range(1, ds.num_states):
            hum = normalize(np.asarray(ds.pas(s)))
            out[s - 1] = ssim_images(hum, empty)
            pb.update(1)
    return out


def run(args) -> int:
    from ..data.store import open_dataset
    from ..rf.bartlett_ref import normalize

    ds = open_dataset(args.dataset)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    summary = {"dataset": str(ds.path), "task": ds.task, "num_antennas": ds.num_antennas,
               "num_states": ds.num_states}
    written = []

    # 1) SSIM empty vs person (only datasets with a person)
    ss = None
    if ds.num_states > 1:
        ss = ssim_empty_vs_person(ds)
        summary.update({"ssim_mean": float(ss.mean()), "ssim_median": float(np.median(ss)),
                        "share_below_0.9": float((ss < 0.9).mean())})
        fig, ax = plots.subplots(figsize=(6, 4))
        ax.hist(ss.ravel(), bins=50, range=(min(0.0, float(ss.min())), 1.0), color="#4477aa")
        ax.axvline(0.9, color="k", ls="--", lw=1)
        ax.set_xlabel("SSIM(empty PAS, person-present PAS)")
        ax.set_ylabel("images")
        ax.set_title(f"mean {ss.mean():.3f}, {100 * (ss < 0.9).mean():.1f}% below 0.9")
        plots.save(fig, out / "ssim_hist.png", dpi=120)
        written.append("ssim_hist.png")

    # 2) PAS grid: the antenna positions the person changes most (or the first ones)
    rows = max(1, min(args.rows, ds.num_antennas))
    if ss is not None:
        s_idx, a_idx = np.unravel_index(np.argsort(ss, axis=None)[:rows], ss.shape)
        picks = [(int(a), int(s) + 1) for s, a in zip(s_idx, a_idx)]
    else:
        picks = [(int(a), None) for a in np.linspace(0, ds.num_antennas - 1, rows).astype(int)]
    cols = 3 if ss is not None else 1
    fig, axes = plots.subplots(rows, cols, figsize=(4.2 * cols, 1.4 * rows + 0.6), squeeze=False)
    for r, (a, s) in enumerate(picks):
        empty = normalize(np.asarray(ds.pas(0)[a]))
        imgs = [(empty, f"antenna {a}: empty room", "viridis", (0, 1))]
        if s is not None:
            hum = normalize(np.asarray(ds.pas(s)[a]))
            imgs += [(hum, f"person at state {s} (SSIM {ss[s - 1, a]:.2f})", "viridis", (0, 1)),
                     (hum - empty, "person - empty", "RdBu_r", (-1, 1))]
        for c, (img, title, cmap, lim) in enumerate(imgs):
            ax = axes[r, c]
            ax.imshow(img, origin="lower", aspect="auto", cmap=cmap, vmin=lim[0], vmax=lim[1],
                      extent=(0, 360, 1, 90))
            ax.set_title(title, fontsize=8)
            ax.set_xlabel("azimuth (deg)", fontsize=7)
            ax.set_ylabel("elevation (deg)", fontsize=7)
            ax.tick_params(labelsize=6)
    plots.save(fig, out / "pas_grid.png", dpi=110)
    written.append("pas_grid.png")

    # 3) top view of the room
    fig, ax = plots.subplots(figsize=(7, 6))
    scene_file = ds.meta.get("scene", {}).get("file") if isinstance(ds.meta.get("scene"), dict) else None
    if scene_file and Path(scene_file).is_file():
        from ..sim.geometry import RoomGeometry

        RoomGeometry.from_xml(scene_file).plot_top_view(ax, labels=True)
    p = ds.antenna_pos
    sc = ax.scatter(p[:, 0], p[:, 1], c=p[:, 2], s=6, cmap="viridis", label="antenna positions")
    fig.colorbar(sc, ax=ax, label="antenna height z (m)", shrink=0.8)
    f = np.asarray(ds.fixed_pos)
    ax.plot(f[0], f[1], marker="*", ms=16, color="red", ls="none",
            label="fixed TX" if ds.task == "rx" else "fixed array")
    if ds.num_states > 1:
        h = ds.person_pos[1:]
        ax.plot(h[:, 0], h[:, 1], "-o", color="#cc3311", ms=4, lw=1, label="walk (person positions)")
        test = set(int(i) for i in ds.split.person_test)
        for i, (x, y) in enumerate(h[:, :2]):
            if i in test:
                ax.plot(x, y, "s", mfc="none", mec="k", ms=8)
    ax.legend(loc="upper right", fontsize=7)
    ax.set_title(f"{Path(str(ds.path)).name}: {ds.num_antennas} positions, task {ds.task}")
    if not (scene_file and Path(scene_file).is_file()):
        ax.set_aspect("equal")
    plots.save(fig, out / "top_view.png", dpi=120)
    written.append("top_view.png")

    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    print(f"wrote {', '.join(written)} and summary.json to {out}")
    if ss is not None:
        print(f"SSIM empty vs person: mean {summary['ssim_mean']:.3f}, median {summary['ssim_median']:.3f}, "
              f"{100 * summary['share_below_0.9']:.1f}% below 0.9")
    return 0
