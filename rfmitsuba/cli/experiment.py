"""``rfmitsuba experiment motivation|parsimony DATASET --out DIR``: multi-run Stage-1 tables."""
from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("experiment", help="motivation table (SSIM vs positions) or parsimony curve (SSIM vs Gaussians)")
    p.add_argument("kind", choices=["motivation", "parsimony"])
    p.add_argument("dataset", help="dataset folder")
    p.add_argument("--out", required=True, help="folder for the runs and the table")
    p.add_argument("--config", default=None, help="TrainConfig TOML for every run")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    p.add_argument("--counts", default=None, help="comma-separated positions (motivation), caps (parsimony, splat) "
                                                   "or scatterers (parsimony, model=coherent_gaussians)")
    p.add_argument("--quick", action="store_true", help="quick training config and small counts")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..experiments import tables as E
    from .train import build_config

    cfg = build_config(args)
    counts = tuple(int(c) for c in args.counts.split(",")) if args.counts else None
    if args.kind == "motivation":
        counts = counts or (E.QUICK_MOTIVATION_COUNTS if args.quick else E.MOTIVATION_COUNTS)
        E.motivation_table(args.dataset, args.out, counts=counts, cfg=cfg, quiet=args.quiet)
    else:
        if cfg.model == "coherent_gaussians":  # counts are numbers of scatterers
            counts = counts or ((0, 8, 32) if args.quick else (0, 8, 16, 32, 64, 96))
        counts = counts or ((300, 600, 1200, 2400) if args.quick else (500, 1000, 2000, 4000, 8000))
        E.parsimony_curve(args.dataset, args.out, caps=counts, cfg=cfg, quiet=args.quiet)
    from pathlib import Path

    print((Path(args.out) / "table.md").read_text())
    return 0
