"""What a folder of spectra can hold, and how fast it changes with position: the figures of
docs/results/measured/diagnosis.md.

Usage: python scripts/measured_diagnosis.py FOLDER INVERT_DIR OUT_DIR [--ceiling-images 20]

FOLDER is a NeRF2 spectrum folder (or an rfmitsuba dataset), INVERT_DIR what
``rfmitsuba invert FOLDER --out INVERT_DIR`` wrote for it. Writes into OUT_DIR:

- ``pairs_by_distance.png``: for every pair of positions, the SSIM of their two spectra and the
  coherence ``max(|<h_i, h_j>|, |<h_i, twin(h_j)>|)`` of their unit-norm recovered channels, in
  distance bins, beside the coherence a field at the carrier can keep at that distance when
  its waves arrive from all directions alike (``sin(k r) / (k r)``) and from one (1);
- ``diagnosis.json``: those curves, consecutive images (measurement order) against other pairs at
  the same distance, and the per-image ceilings of a phase-only and of a free
  (amplitude and phase) rank-one read-out on ``--ceiling-images`` evenly spaced images.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

BINS_M = [0.0, 0.01, 0.02, 0.04, 0.06, 0.10, 0.20, 0.50, 5.0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder")
    ap.add_argument("invert_dir")
    ap.add_argument("out_dir")
    ap.add_argument("--ceiling-images", type=int, default=20)
    a = ap.parse_args()

    from rfmitsuba.core import plots
    from rfmitsuba.core.ssim import ssim_images
    from rfmitsuba.data.store import open_dataset
    from rfmitsuba.eval import invert as inv
    from rfmitsuba.rf import coarray
    from rfmitsuba.rf.array import SPEED_OF_LIGHT

    ds = open_dataset(a.folder)
    summ = json.loads((Path(a.invert_dir) / "invert.json").read_text())
    H = np.load(Path(a.invert_dir) / "channels.npy")
    imgs = np.asarray(ds.pas(0), np.float64)[:len(H)]
    pos = np.asarray(ds.antenna_pos, np.float64)[:len(H)]
    g = summ["used"]
    geom = inv.Geometry(g["frequency_hz"], g["pitch_m"], g["elevation_start_deg"])
    k = 2 * np.pi * g["frequency_hz"] / SPEED_OF_LIGHT
    out = Path(a.out_dir)
    out.mkdir(parents=True, exist_ok=True)

    # pairs: coherence of all, image SSIM of up to 150 per bin
    n = len(H)
    i, j = np.triu_indices(n, 1)
    dist = np.linalg.norm(pos[i] - pos[j], axis=1)
    coh = np.maximum(np.abs(np.sum(np.conj(H[i]) * H[j], 1)), np.abs(np.sum(np.conj(H[i]) * coarray.twin(H[j]), 1)))
    rng = np.random.default_rng(0)
    rows = []
    for lo, hi in zip(BINS_M[:-1], BINS_M[1:]):
        m = np.flatnonzero((dist > lo) & (dist <= hi))
        if not len(m):
            continue
        pick = rng.choice(m, min(150, len(m)), replace=False)
        s = ssim_images(imgs[i[pick]], imgs[j[pick]])
        mid = float(np.median(dist[m]))
        rows.append({"from_m": lo, "to_m": hi, "pairs": int(len(m)), "median_distance_m": mid,
                     "image_ssim_mean": float(s.mean()), "coherence_mean": float(coh[m].mean()),
                     "isotropic_field_coherence": float(abs(np.sinc(k * mid / np.pi)))})

    # measurement order: consecutive images against other pairs at the same distance
    step = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    s_next = ssim_images(imgs[:-1], imgs[1:])
    order_rows = []
    for lo, hi in [(0.0, 0.01), (0.01, 0.02), (0.02, 0.04), (0.04, 0.10)]:
        m = (step > lo) & (step <= hi)
        other = np.flatnonzero((dist > lo) & (dist <= hi) & (np.abs(i - j) > 1))
        if not m.any() or not len(other):
            continue
        pick = rng.choice(other, min(100, len(other)), replace=False)
        order_rows.append({"from_m": lo, "to_m": hi, "consecutive_pairs": int(m.sum()),
                           "consecutive_ssim": float(s_next[m].mean()), "other_pairs": int(len(pick)),
                           "other_ssim": float(ssim_images(imgs[i[pick]], imgs[j[pick]]).mean())})

    # per-image ceilings of the two rank-one read-outs
    fit = coarray.CoarrayFit(frequency_hz=geom.frequency_hz, pitch_m=geom.pitch_m,
                             elevation_start_deg=geom.elevation_start_deg)
    idx = np.unique(np.linspace(0, n - 1, min(a.ceiling_images, n)).round().astype(int))
    ceil = {"images": [int(x) + 1 for x in idx], "phase_only": [], "free": []}
    for x in idx:
        c = fit.fit(imgs[x])["coefficients"]
        for key, po in (("phase_only", True), ("free", False)):
            h, _ = coarray.invert_channels(c, fit.B, starts=16, seed=int(x), phase_only=po)
            ceil[key].append(float(ssim_images(inv.channel_images(h[None], geom), imgs[x][None])[0]))

    fig, ax = plots.subplots(figsize=(6.4, 4.0))
    d = [r["median_distance_m"] * 100 for r in rows]
    ax.semilogx(d, [r["image_ssim_mean"] for r in rows], "o-", label="spectrum-to-spectrum SSIM")
    ax.semilogx(d, [r["coherence_mean"] for r in rows], "s-", label="coherence of recovered channels")
    ax.semilogx(d, [r["isotropic_field_coherence"] for r in rows], "k--",
                label="a field at the carrier, waves from all directions")
    ax.axhline(1.0, color="k", lw=0.8, ls=":", label="a field at the carrier, one direction")
    plots.label(ax, xlabel="distance between the two positions [cm] (bin medians)", ylabel="mean over pairs")
    ax.set_title(f"{Path(a.folder).name}: how fast the spectra change", fontsize=9)
    plots.save(fig, out / "pairs_by_distance.png")
    (out / "diagnosis.json").write_text(json.dumps({"folder": str(a.folder), "pairs": rows, "order": order_rows, "ceilings": ceil,
                                                    "ceiling_means": {k2: float(np.mean(v)) for k2, v in ceil.items()
                                                                      if k2 != "images"}}, indent=1) + "\n")
    for r in rows:
        print(f"{r['from_m'] * 100:5.1f}-{r['to_m'] * 100:5.1f} cm  pairs {r['pairs']:6d}  SSIM {r['image_ssim_mean']:.3f}  "
              f"coherence {r['coherence_mean']:.3f}  isotropic field {r['isotropic_field_coherence']:.3f}")
    for r in order_rows:
        print(f"{r['from_m'] * 100:4.0f}-{r['to_m'] * 100:3.0f} cm  consecutive {r['consecutive_pairs']:4d} pairs SSIM "
              f"{r['consecutive_ssim']:.3f}; other {r['other_pairs']} pairs SSIM {r['other_ssim']:.3f}")
    print(f"rank-one ceilings on {len(idx)} images: phase-only {np.mean(ceil['phase_only']):.3f}, "
          f"free {np.mean(ceil['free']):.3f}")


if __name__ == "__main__":
    main()
