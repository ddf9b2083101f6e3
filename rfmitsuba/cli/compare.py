"""``rfmitsuba compare DATASET --out DIR``: train methods over seeds on one dataset, tabulate."""
from __future__ import annotations

from ..core import cluster


def register(sub) -> None:
    p = sub.add_parser("compare", help="train and evaluate methods over seeds on one dataset (resumable)")
    p.add_argument("dataset", help="dataset folder with person-present states (rfmitsuba generate), or One Walk folders (static and dynamic)")
    p.add_argument("--out", required=True, help="output folder (report.md, results.json, speed_accuracy.png)")
    p.add_argument("--methods", default=None, help="comma-separated methods (default baseline,end_to_end,ours)")
    p.add_argument("--seeds", default=None, help="comma-separated training seeds (default 0,1,2)")
    p.add_argument("--config", default=None, help="CompareConfig TOML file")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value, e.g. --set train.stage1_iterations=1000 or "
                        "--set 'train.overrides=[\"stage1.optim.lr_amp=0.02\"]'")
    p.add_argument("--reevaluate", action="store_true",
                   help="evaluate finished jobs again (after the evaluation changed); training is kept")
    cluster.add_cli_options(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..core import config as C
    from ..experiments.compare import CompareConfig, compare

    cfg = C.load(CompareConfig, args.config) if args.config else CompareConfig()
    sets = list(args.set)
    if args.methods:
        sets.append("methods=[" + ",".join(f'"{m.strip()}"' for m in args.methods.split(",")) + "]")
    if args.seeds:
        sets.append(f"seeds=[{','.join(str(s) for s in parse_seeds(args.seeds))}]")
    cfg = C.override(cfg, sets) if sets else cfg
    path = compare(args.dataset, args.out, cfg=cfg, reevaluate=args.reevaluate, cluster=cluster.from_cli(args))
    print(path.read_text())
    print(f"report: {path}")
    return 0


def parse_seeds(text: str) -> list[int]:
    """``--seeds 0,1,2`` -> [0, 1, 2]; ConfigError naming the entry that is not a whole number >= 0."""
    from ._values import whole_numbers

    return whole_numbers(text, option="--seeds")
