"""``rfmitsuba eval RUN``: metric-protocol evaluation of a trained run, with floors and plots."""
from __future__ import annotations

from ._values import positive_int


def register(sub) -> None:
    p = sub.add_parser("eval", help="evaluate a trained run on its test split (writes RUN/eval/)")
    p.add_argument("run", help="run folder written by `rfmitsuba train`")
    p.add_argument("--batch", type=positive_int, default=8, help="views per render call")
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from ..eval.run import evaluate_run

    m = evaluate_run(args.run, batch=args.batch)
    print((Path(args.run) / "eval" / "summary.md").read_text())
    return 0 if m["model"]["n"] > 0 else 1
