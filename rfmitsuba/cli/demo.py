"""``rfmitsuba demo --out DIR``: the bedroom demo (data, Baseline, Ours, End-to-End, report)."""
from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("demo", help="bedroom demo: generate data, train Baseline / Ours / End-to-End, report")
    p.add_argument("--out", required=True, help="output folder (resumes)")
    p.add_argument("--size", choices=["default", "tiny"], default="default",
                   help="demo size: SIZES['demo'] or SIZES['demo_tiny'] of rfmitsuba.experiments.sizes")
    p.add_argument("--dataset", default=None, help="use this dataset instead of generating one")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..experiments.demo import run_demo
    from ..experiments.sizes import size_config

    cfg = size_config("demo" if args.size == "default" else "demo_tiny")
    path = run_demo(args.out, cfg=cfg, quiet=args.quiet, dataset=args.dataset)
    print(f"report: {path}")
    return 0
