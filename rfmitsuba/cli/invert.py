"""``rfmitsuba invert DATASET --out DIR``: each spectrum's co-array coefficients and rank-one
channels, their re-render SSIM, and the carrier, pitch and grid the spectra imply
(:mod:`rfmitsuba.eval.invert`)."""
from __future__ import annotations

from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("invert", help="recover each spectrum's co-array coefficients and element channels; "
                                      "report the re-render SSIM and the implied carrier, pitch and grid",
                       description="Writes DIR/invert.json (summary and per-image figures), DIR/coefficients.npy "
                                   "float64 [N, 49], DIR/channels.npy complex128 [N, 16] (unit norm, h_0 real, "
                                   "up to the twin conj(h[::-1])), DIR/geometry_scan.csv and DIR/invert.png "
                                   "(measured, co-array and channel re-renders).")
    p.add_argument("dataset", help="NeRF2 spectrum folder or rfmitsuba dataset (its empty-room state)")
    p.add_argument("--out", required=True, help="folder for the results (created)")
    p.add_argument("--frequency-hz", type=float, default=None,
                   help="stated carrier [Hz] (default: the dataset's)")
    p.add_argument("--pitch-m", type=float, default=None,
                   help="stated element pitch [m] (default: half a wavelength at the carrier)")
    p.add_argument("--elevation-start", default="auto",
                   help="elevation [deg] of the images' row 0: 'auto' (the better of 0 and 1 by the co-array "
                        "fit), or a number (a NeRF2 folder's images start at 0, this project's grid at 1)")
    p.add_argument("--images", type=int, default=0, help="invert only the first N images (default: all)")
    p.add_argument("--scan-images", type=int, default=12,
                   help="images (evenly spaced) that the geometry scan fits (default 12)")
    p.add_argument("--starts", type=int, default=16, help="seeded starts of each channel fit; a fit stops at the first exact one (default 16)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from ..core.atomic import write_json, write_text
    from ..core.errors import ConfigError
    from ..core.folder_lock import folder_lock
    from ..data.store import open_dataset
    from ..eval import invert as inv_mod
    from ..rf.array import SPEED_OF_LIGHT
    from ..rf.bartlett_ref import normalize

    ds = open_dataset(args.dataset)
    if args.images < 0:
        raise ConfigError(f"--images must be >= 0, got {args.images}")
    imgs = normalize(ds.pas(0)[:args.images or None]).astype(np.float64)
    f_hz = float(args.frequency_hz or ds.frequency_hz)
    pitch = float(args.pitch_m) if args.pitch_m else 0.5 * SPEED_OF_LIGHT / f_hz
    if not (f_hz > 0 and pitch > 0):
        raise ConfigError(f"--frequency-hz and --pitch-m must be positive, got {f_hz!r}, {pitch!r}")
    if args.elevation_start == "auto":
        starts_deg = inv_mod.ELEVATION_STARTS_DEG
    else:
        try:
            starts_deg = (float(args.elevation_start),)
        except ValueError:
            raise ConfigError(f"--elevation-start must be 'auto' or a number of degrees, "
                              f"got {args.elevation_start!r}") from None
    out = Path(args.out)
    with folder_lock(out, what="invert"):
        n_scan = max(1, min(int(args.scan_images), len(imgs)))
        pick = np.unique(np.linspace(0, len(imgs) - 1, n_scan).round().astype(int))
        implied, rows = inv_mod.scan_geometry(imgs[pick], frequency_hz=f_hz, pitch_m=pitch,
                                              elevation_starts_deg=starts_deg)
        # the channels are recovered on the stated array and carrier, on the implied grid
        used = inv_mod.Geometry(frequency_hz=f_hz, pitch_m=pitch, elevation_start_deg=implied.elevation_start_deg)
        res = inv_mod.invert_images(imgs, used, starts=args.starts, keep_images=True, quiet=args.quiet)
        res.scan = rows
        stated = inv_mod.Geometry(frequency_hz=f_hz, pitch_m=pitch,
                                  elevation_start_deg=1.0 if args.elevation_start == "auto" else starts_deg[0])
        summ = inv_mod.summary(res, stated=stated)
        summ["dataset"] = str(ds.path)
        summ["per_image"] = [{"image": i + 1, "coarray_ssim": float(a), "channel_ssim": float(b), "beta": float(c),
                              "magnitude_ratio": float(d)}
                             for i, (a, b, c, d) in enumerate(zip(res.coarray_ssim, res.channel_ssim, res.beta,
                                                                  res.magnitude_ratio))]
        np.save(out / "coefficients.npy", res.coefficients)
        np.save(out / "channels.npy", res.channels)
        write_text(out / "geometry_scan.csv", "elevation_start_deg,pitch_wavelengths,ssim_mean\n" + "".join(
            f"{r['elevation_start_deg']:g},{r['pitch_wavelengths']:.4f},{r['ssim_mean']:.5f}\n" for r in rows))
        write_json(out / "invert.json", summ, end="\n")
        inv_mod.figure(imgs, res, out / "invert.png")
    s, imp = summ, summ.get("implied", {})
    print(f"{s['images']} spectra of {ds.path}: co-array fit SSIM {s['coarray_ssim']['mean']:.3f} mean "
          f"({s['coarray_ssim']['min']:.3f} min); rank-one channels {s['channel_ssim']['mean']:.3f} mean, "
          f"{s['channel_ssim']['median']:.3f} median; element magnitude min/max {s['magnitude_ratio']['median']:.2f} "
          f"median (1 = phase-only)")
    if imp:
        print(f"implied: row 0 at {imp['elevation_start_deg']:g} deg elevation, pitch {imp['pitch_wavelengths']:.3f} "
              f"wavelengths = {imp['frequency_hz_at_stated_pitch'] / 1e6:.1f} MHz at {pitch:g} m, or "
              f"{imp['pitch_m_at_stated_frequency']:.4f} m at {f_hz / 1e6:g} MHz")
    print(f"written to {out} (invert.json, coefficients.npy, channels.npy, geometry_scan.csv, invert.png)")
    return 0
