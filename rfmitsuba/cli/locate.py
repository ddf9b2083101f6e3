"""``rfmitsuba locate RUN``: where a person stands, from the PAS they change, with a trained
two-stage run (:mod:`rfmitsuba.eval.locate`)."""
from __future__ import annotations

import argparse

from ._values import positive_int


def _nonnegative_int(text: str) -> int:
    tok = text.strip()
    if not (tok.isascii() and tok.isdigit()):
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number >= 0")
    return int(tok)


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not v > 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r} is not a number > 0")
    return v


def register(sub) -> None:
    from ..eval.locate import LOSSES, REFERENCES, REGIONS

    p = sub.add_parser(
        "locate", help="where a person stands, from PAS, with a trained two-stage run (Ours); without --pas, "
                       "scores every held-out walk position of the run's dataset",
        description="Minimises the loss between the PAS the run renders with the person at p and the given PAS "
                    "over the feet position p: a coarse grid over the walk's box (or the room's free space), then descent (Dr.Jit AD "
                    "where the person field allows it, else Nelder-Mead). Without --pas, every held-out walk "
                    "position of the run's dataset is located from its PAS at the test antenna positions and "
                    "scored beside the fingerprint and centre floors (OUT/report.md, locate.json, locate.png).")
    p.add_argument("run", help="an Ours job folder (stage1.json, stage2/), or a comparison folder (its seed<k>/ours) "
                               "or a demo folder (its ours/)")
    p.add_argument("--pas", help="PAS with the person present, one person position: .npy float [K, 90, 360] or "
                                 "[90, 360] (raw or normalised; elevation x azimuth)")
    p.add_argument("--positions", help="with --pas: the moving device's position of each PAS [m]: .npy [K, 3], or "
                                       "text with x y z per line")
    p.add_argument("--empty", help="with --pas: the empty room's PAS at the same positions (.npy, one per PAS); the "
                                   "model's change is then fitted on top of them, so its background's error cancels")
    p.add_argument("--out", help="folder for locate.json (scoring the held-out walk also report.md, locate.png); "
                                 "required without --pas")
    p.add_argument("--antennas", choices=["all", "test"], default="all",
                   help="scoring: the antenna positions of each query, every one of the dataset's (default: one "
                        "frame) or its test antennas only")
    p.add_argument("--reference", choices=list(REFERENCES), default="empty",
                   help="scoring: empty (default): fit the model's change on top of the empty room's measured PAS "
                        "at the same antennas; none: compare the model's PAS with the query as it is")
    p.add_argument("--views", type=_nonnegative_int, default=0,
                   help="scoring: PAS per query, a seeded subset of those antennas (default 0: all)")
    p.add_argument("--grid", type=_positive_float, default=0.25, help="coarse grid spacing [m] (default 0.25)")
    p.add_argument("--starts", type=positive_int, default=4, help="descent starts from the grid's best (default 4)")
    p.add_argument("--steps", type=positive_int, default=30, help="descent steps per start (default 30)")
    p.add_argument("--loss", choices=list(LOSSES), default="train",
                   help="train: 0.8 L1 + 0.2 (1 - SSIM), the training loss (default); ssim: 1 - SSIM")
    p.add_argument("--downsample", type=positive_int, default=2,
                   help="compare d x d block means of the PAS (default 2: 45 x 180; 1: 90 x 360)")
    p.add_argument("--region", choices=list(REGIONS), default="walk",
                   help="search region: the training walk's box grown by 0.5 m (default; the person field is "
                        "trained there), or the known room's whole free space")
    p.add_argument("--descent", choices=["auto", "ad", "nelder_mead", "none"], default="auto",
                   help="local search after the grid (auto: AD where the person field is differentiable in the "
                        "position, else Nelder-Mead; none: the grid alone)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args) -> int:
    import shlex
    import sys
    from pathlib import Path

    from ..core.atomic import write_json_with_numpy, write_text
    from ..core.errors import ConfigError
    from ..core.folder_lock import writer
    from ..eval import locate as L

    opts = {"grid_m": args.grid, "starts": args.starts, "steps": args.steps, "loss": args.loss,
            "downsample": args.downsample, "region": args.region, "descent": args.descent}
    if args.pas is None:
        if args.positions is not None or args.empty is not None:
            raise ConfigError("--positions and --empty go with --pas (the positions and empty room of the given PAS)")
        if args.out is None:
            raise ConfigError("scoring the held-out walk (no --pas) needs --out for its report")
        with writer(args.out, what="locate"):
            res = L.evaluate_locate(args.run, antennas=args.antennas, views=args.views, reference=args.reference,
                                    quiet=args.quiet, **opts)
            out = Path(args.out)
            write_json_with_numpy(out / "locate.json", res)
            L.plot_locate(out / "locate.png", res)
            command = "rfmitsuba " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:] else None
            text = L.report_markdown(res, command=command) + "\n![true and estimated positions](locate.png)\n"
            write_text(out / "report.md", text)
        print(text)
        return 0
    if args.positions is None:
        raise ConfigError("--pas needs --positions (the moving device's position of each PAS)")
    from ..eval.predict import read_positions

    pas = L.read_pas(args.pas)
    positions = read_positions(args.positions)
    empty = L.read_pas(args.empty) if args.empty is not None else None
    rows = []
    for label, jd in L.job_folders(args.run):
        model = L.open_two_stage(jd)
        r = L.locate(model, pas, positions, empty=empty, **opts)
        rows.append({"job": label, "folder": str(jd), **r})
        x, y, z = r["position"]
        print(f"{label}: person at x = {x:.3f} m, y = {y:.3f} m (feet z = {z:.2f} m), loss {r['loss']:.5f} "
              f"({r['descent']} descent, {r['views']} PAS, {r['losses_evaluated']} losses)")
    if args.out is not None:
        with writer(args.out, what="locate"):
            write_json_with_numpy(Path(args.out) / "locate.json",
                                  {"run": str(args.run), "pas": str(args.pas), "positions": str(args.positions),
                                   "empty": None if args.empty is None else str(args.empty),
                                   "settings": opts, "estimates": rows})
    return 0
