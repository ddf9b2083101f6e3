"""Where each specular path of a known room exists: a top view per image, every antenna position
of a dataset coloured by what the ray cast finds (clear, blocked, absent).

Usage: python scripts/visibility_figure.py DATASET OUT.png [--images direct,x=0.00,z=0.00,bed:z=0.50]

The dataset must name its room (a Sionna dataset made by ``rfmitsuba generate``). The images are
those of the coherent Gaussian field's known-room start (room order 2, furniture faces,
every plane sequence its own image; ``rfmitsuba.rf.images.scene_image_maps``), cast by
``rfmitsuba.sim.visibility.SpecularVisibility``. Made docs/results/coherent_field/bedroom_visibility.png
from ``rfmitsuba generate bedroom --task rx --positions 900 --person-positions 0``.
"""
from __future__ import annotations

import argparse

import numpy as np

import rfmitsuba  # noqa: F401 - finds libLLVM before Dr.Jit starts
from rfmitsuba.data.views import TrainData
from rfmitsuba.rf.images import scene_image_maps
from rfmitsuba.sim.geometry import RoomGeometry
from rfmitsuba.sim.visibility import SpecularVisibility


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset")
    ap.add_argument("out")
    ap.add_argument("--images", default="direct,x=0.00,z=0.00,door:y=-0.08,bed:z=0.50,x=0.00|z=0.00")
    a = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = TrainData.open(a.dataset)
    if data.scene_xml is None:
        raise SystemExit(f"{a.dataset} names no room")
    geo = RoomGeometry.from_xml(data.scene_xml)
    maps = scene_image_maps(geo, room_order=2, furniture_order=1, distinct_paths=True, furniture_planes="faces")
    idx = np.arange(len(data.antenna_pos))
    x, y, q = data.positions(idx)
    ex, cl = SpecularVisibility.from_xml(data.scene_xml)(x, y, maps.planes, maps.order)
    names = [n for n in a.images.split(",") if n]
    missing = [n for n in names if n not in maps.label]
    if missing:
        raise SystemExit(f"no image {missing}; known: {', '.join(maps.label)}")
    cols = 3
    rows = (len(names) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.6 * rows), squeeze=False)
    for ax, name in zip(axes.ravel(), names):
        i = maps.label.index(name)
        geo.plot_top_view(ax, labels=False)
        for mask, colour, what in ((cl[:, i], "#1a9850", "clear"), (ex[:, i] & ~cl[:, i], "#fdae61", "blocked"),
                                   (~ex[:, i], "#bbbbbb", "absent")):
            ax.scatter(q[mask, 0], q[mask, 1], s=5, c=colour, label=f"{what} {mask.mean():.0%}")
        src = y[0] if data.task == "rx" else x[0]
        ax.plot(*src[:2], marker="*", ms=12, c="k")
        ax.set_title(f"{name} (order {maps.order[i]})", fontsize=9)
        ax.legend(fontsize=7, loc="upper right", markerscale=2)
    for ax in axes.ravel()[len(names):]:
        ax.axis("off")
    fig.suptitle(f"ray-cast visibility of image paths, {len(idx)} positions of {data.path.name} "
                 f"(star: the fixed device; colours: the moving device)", fontsize=10)
    fig.tight_layout()
    fig.savefig(a.out, dpi=80)
    print(a.out)


if __name__ == "__main__":
    main()
