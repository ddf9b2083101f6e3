"""``rfmitsuba demo --out DIR``: the bedroom demo (data, Baseline, Ours, End-to-End, report)."""
from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("demo", help="bedroom demo: generate data, train Baseline / Ours / End-to-End, report")
    p.add_argument("--out", required=True, help="output folder (resumes)")
    p.add_argument("--size", choices=["default", "tiny"], default="default", help="demo size")
    p.add_argument("--dataset", default=None, help="use this dataset instead of generating one")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..experiments.demo import SIZES, run_demo

    path = run_demo(args.out, cfg=SIZES[args.size], quiet=args.quiet, dataset=args.dataset)
    print(f"report: {path}")
    return 0
