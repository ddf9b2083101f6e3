"""``rfmitsuba nerf2like --out DIR``: simulate a NeRF2-like RFID folder (the NeRF2-like protocol)."""
from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("nerf2like", help="simulate NeRF2-like RFID spectra (moving tags, fixed 4x4 gateway about 5 m "
                                         "away, 920 MHz, phase offsets, noise, phase-only read-out, 8-bit PNG) "
                                         "as a NeRF2 folder")
    p.add_argument("--out", required=True, help="folder to write (a complete folder of the same configuration is kept)")
    p.add_argument("--tags", type=int, default=200, help="tag positions along 9 mm trajectories (default 200)")
    p.add_argument("--snr", type=float, default=20.0, help="signal-to-noise ratio in dB (default 20; inf = none)")
    p.add_argument("--phase-error", type=float, default=30.0,
                   help="per-element phase offsets uniform in +- this many degrees (default 30)")
    p.add_argument("--diffuse", type=float, default=0.0,
                   help="scattering coefficient of every material in [0, 1]: Sionna RT also traces diffuse "
                        "reflections, as rough real surfaces scatter (default 0: specular paths only)")
    p.add_argument("--coupling", type=float, default=float("-inf"),
                   help="mutual coupling of adjacent elements in dB, e.g. -20 (default: none)")
    p.add_argument("--position-error", type=float, default=0.0, metavar="MM",
                   help="the stated tag positions (tx_pos.csv) are off from where each spectrum was taken by "
                        "Gaussian errors of this standard deviation per axis, in mm, as tracked positions are "
                        "(default 0)")
    p.add_argument("--readout", choices=("phase_only", "amplitude"), default="phase_only",
                   help="Bartlett read-out: phase_only (NeRF2's, the default) or amplitude (the measured RFID images')")
    p.add_argument("--drift-db", type=float, default=0.0, metavar="DB",
                   help="measurement drift: each measurement's element gains vary by this many dB (standard "
                        "deviation; default 0: none)")
    p.add_argument("--drift-deg", type=float, default=0.0, metavar="DEG",
                   help="measurement drift: each measurement's element phases vary by this many degrees (default 0)")
    p.add_argument("--drift-correlation", type=float, default=0.0, metavar="RHO",
                   help="correlation of the drift between consecutive tags of a path, in [0, 1) (default 0)")
    p.add_argument("--region", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="size of the tag region in metres (default 1.6 1.3 0.9; the measured RFID folder's "
                        "tags span about 0.5 1.0 0.2)")
    p.add_argument("--seed", type=int, default=0, help="trajectories, offsets, noise and the 160/40 split")
    p.add_argument("--scene", default="large_room", help="built-in room or XML (default large_room, fits 5 m)")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..sim.nerf2like import make_nerf2like

    out = make_nerf2like(args.out, num_tags=args.tags, snr_db=args.snr, phase_error_deg=args.phase_error,
                         seed=args.seed, scene=args.scene, diffuse=args.diffuse,
                         coupling_db=args.coupling, position_error_m=args.position_error / 1000.0,
                         readout=args.readout, drift_db=args.drift_db, drift_deg=args.drift_deg,
                         drift_correlation=args.drift_correlation,
                         **({"region_size": tuple(args.region)} if args.region else {}), quiet=args.quiet)
    print(f"NeRF2-like folder {out}")
    print(f"next: rfmitsuba train {out} --out RUN --set model=coherent_gaussians  (add --split block for the slab split)")
    return 0
